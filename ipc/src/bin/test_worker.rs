//! A worker for the transport's tests and benchmarks: answers every job with one `Progress` and a `Done` whose
//! `samples` is `robot * 100 + trajectory` and `content_hash` is `seed ^ job_id`. Jobs with `robot == 666` sleep
//! 60 s first when `DYNFORGE_TEST_HANG=1` (a job to kill the worker in), `robot == 777` are `Discarded` with reason
//! "collision", `robot == 888` are dropped without any report.
//!
//! Usage: dynforge-ipc-test-worker RUN_ID SLOT
//!        dynforge-ipc-test-worker coordinator RUN_ID   (a coordinator publishing a status every 10 ms until
//!                                                       killed; prints "ready" once it published)

use std::time::Duration;

use std::io::Write;

use dynforge_ipc::{Coordinator, RunId, StatusMsg, Worker};
use dynforge_proto::job::JobReport;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Err(e) = run(&args) {
        eprintln!("dynforge-ipc-test-worker: {e}");
        std::process::exit(1);
    }
}

fn run(args: &[String]) -> Result<(), Box<dyn std::error::Error>> {
    if let [_, mode, run_id] = args
        && mode == "coordinator"
    {
        return coordinator(&RunId::new(run_id)?);
    }
    let [_, run_id, slot] = args else { return Err("usage: dynforge-ipc-test-worker RUN_ID SLOT".into()) };
    let run = RunId::new(run_id)?;
    let hang = std::env::var_os("DYNFORGE_TEST_HANG").is_some_and(|v| v == "1");
    let mut worker = Worker::new(&run, slot.parse()?)?;
    while let Some(job) = worker.next_job()? {
        if job.job.robot == 888 {
            continue;
        }
        if hang && job.job.robot == 666 {
            std::thread::sleep(Duration::from_secs(60));
        }
        worker.report(&JobReport::Progress { job_id: job.job_id, permille: 500 })?;
        let report = if job.job.robot == 777 {
            JobReport::Discarded { job_id: job.job_id, reason: "collision".into() }
        } else {
            let samples = job.job.robot * 100 + u64::from(job.job.trajectory);
            JobReport::Done { job_id: job.job_id, samples, content_hash: job.job.seed ^ job.job_id }
        };
        worker.report(&report)?;
    }
    Ok(())
}

fn coordinator(run: &RunId) -> Result<(), Box<dyn std::error::Error>> {
    let mut coord = Coordinator::new(run, 1)?;
    let mut status = StatusMsg { total: 1000, coordinator_pid: std::process::id(), ..StatusMsg::default() };
    loop {
        status.done += 1;
        coord.publish_status(&status)?;
        if status.done == 1 {
            println!("ready");
            std::io::stdout().flush()?;
        }
        coord.wait(Duration::from_millis(10))?;
    }
}
