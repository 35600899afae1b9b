//! Work spread over the cores, with results that do not depend on how many there are (the determinism every
//! output of dynforge keeps). The shard reader, the dynamics and burn's CPU backend each use one core per call,
//! so dynforge runs independent calls side by side itself.

/// `f` of every item, in item order, computed on one thread per core (thread t takes items t, t + n, ...). The
/// result does not depend on the number of cores.
pub fn map_in_order<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(items.len()).max(1);
    let f = &f;
    let mut per_thread: Vec<std::vec::IntoIter<R>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| s.spawn(move || items.iter().skip(t).step_by(threads).map(f).collect::<Vec<R>>()))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)).into_iter()).collect()
    });
    (0..items.len()).map(|i| per_thread[i % threads].next().expect("one result per item")).collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn results_come_back_in_item_order() {
        let items: Vec<u64> = (0..37).collect();
        assert_eq!(super::map_in_order(&items, |&i| i * i), items.iter().map(|i| i * i).collect::<Vec<_>>());
        assert!(super::map_in_order(&[] as &[u64], |&i| i).is_empty());
    }
}
