//! The transport with real worker processes (same-process nodes always count as alive, so deaths need processes).

mod common;

use std::collections::HashMap;
use std::io::BufRead;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{TestRun, Workers, process_cpu, start, thread_cpu, wait_ready};
use dynforge_ipc::{Coordinator, IpcError, StatusMsg, StatusReader};
use dynforge_proto::job::{Job, JobReport, JobRequest};

fn job(job_id: u64, seed: u64, robot: u64, trajectory: u32) -> JobRequest {
    JobRequest { job_id, job: Job { seed, robot, trajectory } }
}

/// Waits for the final report of the job in flight on slot `k` (other slots' reports are returned in `others`).
fn final_of(coord: &mut Coordinator, k: usize, others: &mut Vec<(usize, JobReport)>) -> JobReport {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        for (slot, report) in coord.wait(Duration::from_millis(500)).unwrap() {
            if slot == k && report.is_final() {
                return report;
            }
            others.push((slot, report));
        }
        assert!(Instant::now() < deadline, "no final report from slot {k} within 10 s");
    }
}

/// Waits for the final reports of the jobs in flight on `slots`.
fn finals_of(coord: &mut Coordinator, slots: &[usize]) -> HashMap<usize, JobReport> {
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut out = HashMap::new();
    while out.len() < slots.len() {
        for (slot, report) in coord.wait(Duration::from_millis(500)).unwrap() {
            assert!(slots.contains(&slot), "report {report:?} from slot {slot}");
            if report.is_final() {
                assert!(out.insert(slot, report.clone()).is_none(), "second final report {report:?}");
            }
        }
        assert!(Instant::now() < deadline, "no final reports from all of {slots:?} within 10 s");
    }
    out
}

fn expected(j: &JobRequest) -> JobReport {
    if j.job.robot == 888 {
        JobReport::Failed { job_id: j.job_id, message: "the worker dropped the job without a final report".into() }
    } else if j.job.robot == 777 {
        JobReport::Discarded { job_id: j.job_id, reason: "collision".into() }
    } else {
        JobReport::Done {
            job_id: j.job_id,
            samples: j.job.robot * 100 + u64::from(j.job.trajectory),
            content_hash: j.job.seed ^ j.job_id,
        }
    }
}

#[test]
fn two_workers_answer_fifty_jobs_exactly_once() {
    let run = TestRun::new("rt");
    let mut workers = Workers::default();
    {
        let mut coord = Coordinator::new(&run.id, 2).unwrap();
        start(&mut coord, &mut workers, &run.id, 2);
        let jobs: Vec<JobRequest> = (0..50)
            .map(|i| job(1000 + i, 42, [777, 888].get(i as usize % 20).copied().unwrap_or(i % 7), (i % 16) as u32))
            .collect();

        // One job in flight per worker.
        coord.send(0, &jobs[0]).unwrap();
        assert!(matches!(coord.send(0, &jobs[1]), Err(IpcError::Busy { slot: 0, job_id: 1000 })));
        assert!(matches!(coord.send(2, &jobs[1]), Err(IpcError::SlotOutOfRange { .. })));
        let mut reports = Vec::new();
        let first = final_of(&mut coord, 0, &mut reports);
        assert_eq!(first, expected(&jobs[0]));

        let mut queue = jobs[1..].iter();
        let mut busy: [Option<u64>; 2] = [None, None];
        let mut finals = HashMap::from([(first.job_id(), first)]);
        let mut progress = reports.len();
        let deadline = Instant::now() + Duration::from_secs(30);
        while finals.len() < jobs.len() {
            for (k, b) in busy.iter_mut().enumerate() {
                if b.is_none()
                    && let Some(j) = queue.next()
                {
                    coord.send(k, j).unwrap();
                    *b = Some(j.job_id);
                }
            }
            for (k, r) in coord.wait(Duration::from_secs(1)).unwrap() {
                assert_eq!(Some(r.job_id()), busy[k], "report {r:?} from slot {k}");
                if r.is_final() {
                    assert!(finals.insert(r.job_id(), r.clone()).is_none(), "second final report {r:?}");
                    busy[k] = None;
                } else {
                    assert_eq!(r, JobReport::Progress { job_id: r.job_id(), permille: 500 });
                    progress += 1;
                }
            }
            assert!(Instant::now() < deadline, "only {} of 50 jobs answered in 30 s", finals.len());
        }
        for j in &jobs {
            assert_eq!(finals[&j.job_id], expected(j));
        }
        assert_eq!(progress, 50 - 3, "one progress report per job, none for the 3 dropped jobs");
        assert!(coord.wait(Duration::from_millis(50)).unwrap().is_empty(), "nothing after the final reports");
        assert!(coord.dead_workers().is_empty());
        // Shutting down stops the workers and leaves nothing behind.
        assert!(coord.shutdown(Duration::from_secs(3)).unwrap());
    }
    workers.join(Duration::from_secs(3));
    assert!(run.files().is_empty(), "shutdown left {:?}", run.files());
}

#[test]
fn killed_worker_is_detected_and_replaced_in_its_slot() {
    let run = TestRun::new("kill");
    let mut workers = Workers::default();
    let mut coord = Coordinator::new(&run.id, 2).unwrap();
    workers.spawn(&run.id, 0, true);
    workers.spawn(&run.id, 1, false);
    coord.attach_worker(0).unwrap();
    coord.attach_worker(1).unwrap();
    wait_ready(&coord, 0);
    wait_ready(&coord, 1);
    assert!(coord.dead_workers().is_empty());
    assert!(coord.worker_pid(0).is_some());

    let hanging = job(1, 5, 666, 2);
    coord.send(0, &hanging).unwrap();
    coord.send(1, &job(2, 5, 3, 4)).unwrap();
    let mut others = Vec::new();
    assert_eq!(final_of(&mut coord, 1, &mut others), expected(&job(2, 5, 3, 4)));
    std::thread::sleep(Duration::from_millis(100)); // worker 0 is asleep in its job now
    assert!(coord.wait(Duration::from_millis(10)).unwrap().is_empty());

    let killed = Instant::now();
    workers.kill(0); // SIGKILL, reaped
    let dead = loop {
        let dead = coord.dead_workers();
        if !dead.is_empty() {
            break dead;
        }
        assert!(killed.elapsed() < Duration::from_secs(1), "death of worker 0 not seen within 1 s");
        std::thread::sleep(Duration::from_millis(10));
    };
    eprintln!("kill -9 of worker 0 detected after {:?} (10 ms polling)", killed.elapsed());
    assert_eq!(dead, vec![0]);
    assert_eq!(coord.in_flight(0), Some(hanging), "the lost job is still known");
    assert!(coord.dead_workers().is_empty(), "a death is reported once");
    assert!(!coord.worker_ready(0));
    assert!(matches!(coord.send(0, &hanging), Err(IpcError::WorkerNotReady(0))));
    assert!(coord.wait(Duration::from_millis(10)).unwrap().is_empty(), "no report for the lost job");

    // A replacement in the same slot serves the re-sent job; slot 1 is unaffected.
    workers.spawn(&run.id, 0, false);
    coord.attach_worker(0).unwrap();
    assert_eq!(coord.in_flight(0), None);
    wait_ready(&coord, 0);
    coord.send(0, &hanging).unwrap();
    coord.send(1, &job(3, 5, 4, 5)).unwrap();
    let finals = finals_of(&mut coord, &[0, 1]);
    assert_eq!(finals[&0], expected(&hanging));
    assert_eq!(finals[&1], expected(&job(3, 5, 4, 5)));
    assert!(coord.dead_workers().is_empty());
    drop(coord);
    workers.join(Duration::from_secs(3));
}

#[test]
fn two_runs_on_one_host_do_not_interfere() {
    let (ra, rb) = (TestRun::new("ia"), TestRun::new("ib"));
    let (mut wa, mut wb) = (Workers::default(), Workers::default());
    let mut ca = Coordinator::new(&ra.id, 1).unwrap();
    let mut cb = Coordinator::new(&rb.id, 1).unwrap();
    // The second coordinator is refused, naming the first one's process.
    match Coordinator::new(&ra.id, 1) {
        Err(e @ IpcError::CoordinatorAlreadyRunning { pid: Some(pid) }) => {
            assert_eq!(pid, std::process::id() as i32);
            assert!(e.to_string().contains(&format!("(pid {pid})")), "{e}");
        }
        Err(e) => panic!("refused for another reason: {e}"),
        Ok(_) => panic!("a second coordinator was accepted"),
    }
    start(&mut ca, &mut wa, &ra.id, 1);
    start(&mut cb, &mut wb, &rb.id, 1);
    for i in 0..20 {
        // Same slot, same job ids, different seeds: each run must see only its own answers.
        let (ja, jb) = (job(i, 100, i, 1), job(i, 200, i, 2));
        ca.send(0, &ja).unwrap();
        cb.send(0, &jb).unwrap();
        let mut others = Vec::new();
        assert_eq!(final_of(&mut ca, 0, &mut others), expected(&ja));
        assert_eq!(final_of(&mut cb, 0, &mut others), expected(&jb));
        assert!(others.iter().all(|(_, r)| matches!(r, JobReport::Progress { job_id, .. } if *job_id == i)));
    }
    let killed = Instant::now();
    wb.kill(0);
    while cb.dead_workers().is_empty() {
        assert!(killed.elapsed() < Duration::from_secs(1));
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(ca.dead_workers().is_empty(), "run a does not see run b's death");
    ca.send(0, &job(99, 100, 1, 1)).unwrap();
    assert_eq!(final_of(&mut ca, 0, &mut Vec::new()), expected(&job(99, 100, 1, 1)));
    drop((ca, cb));
    wa.join(Duration::from_secs(3));
}

#[test]
fn status_reader_sees_a_live_coordinator_and_never_disturbs_a_dead_one() {
    let run = TestRun::new("st");
    // No coordinator: None, and nothing created.
    assert!(StatusReader::open(&run.id).unwrap().is_none());
    assert!(run.files().is_empty(), "StatusReader::open left {:?}", run.files());

    let s1 = StatusMsg {
        done: 10,
        discarded: 1,
        failed: 2,
        in_flight: 2,
        total: 100,
        workers_alive: 2,
        ..Default::default()
    };
    let s2 = StatusMsg { done: 11, rate_per_s: 3.5, updated_unix_ms: 123, ..s1 };
    {
        let mut coord = Coordinator::new(&run.id, 1).unwrap();
        coord.publish_status(&s1).unwrap();
        let mut reader = StatusReader::open(&run.id).unwrap().expect("a live coordinator");
        coord.wait(Duration::from_millis(10)).unwrap(); // hands its last status to the new monitor
        assert_eq!(reader.latest_timeout(Duration::from_secs(1)), Some(s1));
        coord.publish_status(&s2).unwrap();
        assert_eq!(reader.latest(), Some(s2));
        assert_eq!(reader.latest(), Some(s2), "latest stays until a newer one arrives");
        assert!(reader.coordinator_alive());
        let mut second = StatusReader::open(&run.id).unwrap().unwrap();
        coord.wait(Duration::from_millis(10)).unwrap();
        assert_eq!(second.latest_timeout(Duration::from_secs(1)), Some(s2));
    }
    assert!(StatusReader::open(&run.id).unwrap().is_none(), "coordinator dropped");

    // A coordinator in another process, then killed: the reader returns None and leaves it to the next coordinator.
    let mut child =
        Command::new(common::WORKER_EXE).args(["coordinator", run.id.as_str()]).stdout(Stdio::piped()).spawn().unwrap();
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    assert_eq!(line.trim(), "ready");
    let mut reader = StatusReader::open(&run.id).unwrap().expect("the coordinator process is alive");
    let s = reader.latest_timeout(Duration::from_secs(2)).expect("a status within 2 s");
    assert_eq!((s.total, s.coordinator_pid), (1000, child.id()));
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!reader.coordinator_alive());
    drop(reader);
    let started = Instant::now();
    assert!(StatusReader::open(&run.id).unwrap().is_none(), "dead coordinator");
    eprintln!("StatusReader::open without a live coordinator: {:?}", started.elapsed());

    let mut coord = Coordinator::new(&run.id, 1).unwrap();
    coord.publish_status(&s1).unwrap();
    let mut reader = StatusReader::open(&run.id).unwrap().unwrap();
    coord.publish_status(&s2).unwrap();
    assert_eq!(reader.latest_timeout(Duration::from_secs(1)), Some(s2));
}

/// Round-trip latency of zero-work jobs and the coordinator's CPU while idle (printed; run alone with
/// `--nocapture` for meaningful numbers).
#[test]
fn latency_and_idle_cpu() {
    let run = TestRun::new("lat");
    let mut workers = Workers::default();
    let mut coord = Coordinator::new(&run.id, 1).unwrap();
    start(&mut coord, &mut workers, &run.id, 1);
    let mut lat = Vec::new();
    for i in 0..2200u64 {
        let j = job(i, 1, 1, 1);
        let t = Instant::now();
        coord.send(0, &j).unwrap();
        let r = final_of(&mut coord, 0, &mut Vec::new());
        if i >= 200 {
            lat.push(t.elapsed());
        }
        assert_eq!(r, expected(&j));
    }
    lat.sort();
    let (median, p99) = (lat[lat.len() / 2], lat[lat.len() * 99 / 100]);
    eprintln!("round trip send -> Progress + Done (zero work, 1 worker): median {median:?}, p99 {p99:?}");

    let worker_cpu = process_cpu(workers.pid(0));
    let tick = |coord: &mut Coordinator, scan: bool| {
        let start = (Instant::now(), thread_cpu());
        let mut scans = Duration::ZERO;
        while start.0.elapsed() < Duration::from_secs(2) {
            assert!(coord.wait(Duration::from_millis(100)).unwrap().is_empty());
            if scan {
                let t = Instant::now();
                assert!(coord.dead_workers().is_empty());
                scans += t.elapsed();
                coord.publish_status(&StatusMsg::default()).unwrap();
            }
        }
        let cpu = (thread_cpu() - start.1).as_secs_f64() / start.0.elapsed().as_secs_f64();
        (cpu, scans / 20)
    };
    let (idle, _) = tick(&mut coord, false);
    let (busy, scan) = tick(&mut coord, true);
    let worker_cpu = (process_cpu(workers.pid(0)) - worker_cpu).as_secs_f64() / 4.0;
    eprintln!("idle worker CPU (coordinator liveness check every 500 ms): {:.3} %", worker_cpu * 100.0);
    eprintln!(
        "coordinator CPU: wait(100 ms) only {:.3} %, with dead_workers + publish_status per tick {:.3} % \
         (dead_workers ~{scan:?} with 1 worker)",
        idle * 100.0,
        busy * 100.0
    );
    assert!(busy < 0.1, "coordinator idles at {:.1} % CPU", busy * 100.0);
}

#[test]
fn restarted_coordinator_retires_the_workers_of_a_crashed_one() {
    let run = TestRun::new("re");
    let mut old =
        Command::new(common::WORKER_EXE).args(["coordinator", run.id.as_str()]).stdout(Stdio::piped()).spawn().unwrap();
    let mut line = String::new();
    std::io::BufReader::new(old.stdout.take().unwrap()).read_line(&mut line).unwrap();
    assert_eq!(line.trim(), "ready");
    let mut workers = Workers::default();
    workers.spawn(&run.id, 0, false);
    std::thread::sleep(Duration::from_millis(200)); // the worker joined the old coordinator
    old.kill().unwrap();
    old.wait().unwrap();

    let restarted = Instant::now();
    let mut coord = Coordinator::new(&run.id, 1).unwrap();
    workers.join(Duration::from_secs(2)); // the old worker exits (asked to stop by the new coordinator)
    eprintln!("old worker gone {:?} after the restarted coordinator started", restarted.elapsed());
    start(&mut coord, &mut workers, &run.id, 1);
    coord.send(0, &job(1, 2, 3, 4)).unwrap();
    assert_eq!(final_of(&mut coord, 0, &mut Vec::new()), expected(&job(1, 2, 3, 4)));
    assert!(coord.shutdown(Duration::from_secs(3)).unwrap());
}

#[test]
fn coordinator_process_exits_cleanly_on_sigterm() {
    let run = TestRun::new("sig");
    let mut child = Command::new(common::WORKER_EXE)
        .args(["coordinator", run.id.as_str()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    assert_eq!(line.trim(), "ready");
    let status = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    assert!(status.success());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("interrupted by SIGINT or SIGTERM"), "stderr: {stderr}");
    assert_eq!(out.status.code(), Some(1));
    assert!(StatusReader::open(&run.id).unwrap().is_none());
}
