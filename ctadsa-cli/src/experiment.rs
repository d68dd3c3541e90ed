//! `ctadsa experiment`: a matrix of (case × prior × views × method) completions and the
//! ensembles of its methods (`ctadsa_core::run::experiment`). Without a mode flag it runs every
//! unfinished cell on this machine and collects; `--list`, `--cell I` and `--collect` split that
//! into the steps a cluster runs (one array task per run cell, then one per ensemble cell, then
//! one collect), see docs/CLUSTER.md.

use std::path::PathBuf;
use std::sync::Mutex;

use anyhow::{Result, bail};
use clap::Args;
use ctadsa_core::run::completion::Silent;
use ctadsa_core::run::experiment::Experiment;

use crate::backend::BackendKind;
use crate::complete::Terminal;

#[derive(Args)]
pub struct ExperimentArgs {
    /// Case folders (each with case.json).
    #[arg(long, num_args = 1.., required = true)]
    cases: Vec<PathBuf>,
    /// The matrix (TOML): views, priors, methods; see configs/experiments/.
    #[arg(long)]
    matrix: PathBuf,
    /// Output folder: one sub-folder per cell, and the tables and plots.
    #[arg(long)]
    out: PathBuf,
    /// Backend of every run.
    #[arg(long, value_enum, default_value = "ndarray")]
    backend: BackendKind,
    /// Cells run at the same time, 1 to 256, each on CPU kernel threads of its own
    /// (`--threads-per-job`).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=256))]
    jobs: u16,
    /// CPU kernel threads of each cell when `--jobs` is over 1, 1 to 1,024; by default the
    /// kernel threads there are (`RAYON_NUM_THREADS`, else one per core) shared out among the
    /// jobs, at least one each.
    #[arg(long, value_name = "T", value_parser = clap::value_parser!(u16).range(1..=1024))]
    threads_per_job: Option<u16>,
    /// Overrides for every cell, after the matrix's own (repeatable).
    #[arg(long = "set")]
    overrides: Vec<String>,
    /// Print the cells (index, state, `run` or `ensemble`, label, folder; tab-separated; the
    /// ensembles after every run) and stop.
    #[arg(long, conflicts_with_all = ["cell", "collect"])]
    list: bool,
    /// Run only cell I (0-based, as `--list` numbers them; what a SLURM array task runs). A
    /// finished cell is left as it is.
    #[arg(long, value_name = "I", conflicts_with = "collect")]
    cell: Option<usize>,
    /// Only gather the finished cells into results.csv, table.md and the plots.
    #[arg(long)]
    collect: bool,
}

/// The most kernel threads all jobs together may start (`--jobs` × `--threads-per-job`).
const MAX_KERNEL_THREADS: usize = 4096;

pub fn run(args: ExperimentArgs) -> Result<()> {
    if let Some(threads) = args.threads_per_job {
        let all = usize::from(args.jobs) * usize::from(threads);
        if all > MAX_KERNEL_THREADS {
            bail!(
                "--jobs {} --threads-per-job {threads}: {all} kernel threads in all, at most {MAX_KERNEL_THREADS}",
                args.jobs
            );
        }
    }
    let exp = Experiment::load(&args.matrix, &args.cases, &args.out, &args.overrides)?;
    if args.list {
        use std::io::Write as _;
        let mut out = std::io::stdout().lock();
        for (i, cell) in exp.cells.iter().enumerate() {
            let waits_for = exp.waits_for(i);
            let state = if cell.finished().is_some() {
                "done".to_string()
            } else if cell.stale() {
                "stale (its cell.json is of another configuration or case, or unreadable: runs again)".to_string()
            } else if !waits_for.is_empty() {
                let cells: Vec<String> = waits_for.iter().map(usize::to_string).collect();
                format!("todo (after cells {})", cells.join(", "))
            } else {
                "todo".to_string()
            };
            let kind = if cell.is_ensemble() { "ensemble" } else { "run" };
            match writeln!(out, "{i}\t{state}\t{kind}\t{}\t{}", cell.label(), cell.dir.display()) {
                // The reader has what it wanted (`--list | head`).
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(()),
                other => other?,
            }
        }
        return Ok(());
    }
    std::fs::create_dir_all(&args.out)?;
    if let Some(i) = args.cell {
        let Some(cell) = exp.cells.get(i) else {
            bail!("--cell {i}: the matrix has {} cells (0 to {})", exp.cells.len(), exp.cells.len().saturating_sub(1))
        };
        if cell.finished().is_some() {
            eprintln!("cell {i} ({}) is already finished: {}", cell.label(), cell.dir.display());
            return Ok(());
        }
        eprintln!("cell {i}/{}: {}", exp.cells.len(), cell.label());
        let device = args.backend.device()?.autodiff();
        return match exp.run_cell(i, device, &mut Terminal::new())? {
            Some(_) => Ok(()),
            None => bail!("cell {i} interrupted: run the same command again to redo it"),
        };
    }
    if !args.collect {
        let jobs = usize::from(args.jobs);
        let threads =
            args.threads_per_job.map_or_else(|| threads_per_job(rayon::current_num_threads(), jobs), usize::from);
        run_unfinished(&exp, args.backend, jobs, threads)?;
    }
    let md = exp.collect()?;
    println!("\n{md}");
    let left = exp.cells.len() - exp.finished().len();
    if left > 0 {
        bail!("{left} of {} cell(s) are not finished (the tables hold the finished ones)", exp.cells.len());
    }
    eprintln!("results in {}", args.out.display());
    Ok(())
}

/// The kernel threads of each of `jobs` cells run at once: the `threads` there are shared out,
/// at least one each.
fn threads_per_job(threads: usize, jobs: usize) -> usize {
    (threads / jobs.max(1)).max(1)
}

/// Runs the unfinished cells, `jobs` at a time, each on `threads` kernel threads of its own: the
/// runs, then the ensembles of them; failures are listed at the end (an ensemble of a failed run
/// among them). One at a time, a cell shows its progress bar and Ctrl-C / SIGTERM stop the
/// experiment after saving the cell's checkpoint (the cell is redone on the next run).
fn run_unfinished(exp: &Experiment, backend: BackendKind, jobs: usize, threads: usize) -> Result<()> {
    let todo: Vec<usize> = (0..exp.cells.len()).filter(|&i| exp.cells[i].finished().is_none()).collect();
    eprintln!("{} cells: {} done before, {} to run", exp.cells.len(), exp.cells.len() - todo.len(), todo.len());
    let device = backend.device()?.autodiff();
    let mut failures = Vec::new();
    if jobs <= 1 {
        // In index order: every ensemble comes after the runs it averages.
        let mut terminal = Terminal::new();
        for i in todo {
            let cell = &exp.cells[i];
            eprintln!("cell {}/{}: {}", i + 1, exp.cells.len(), cell.label());
            match exp.run_cell(i, device.clone(), &mut terminal) {
                Ok(Some(_)) => {}
                Ok(None) => bail!("interrupted in cell {i} ({}): run the same command again to go on", cell.label()),
                Err(e) => failures.push(format!("{}: {e:#}", cell.dir.display())),
            }
        }
    } else {
        eprintln!("{jobs} cells at a time, {threads} kernel thread(s) each");
        let (ensembles, runs): (Vec<usize>, Vec<usize>) = todo.into_iter().partition(|&i| exp.cells[i].is_ensemble());
        for phase in [runs, ensembles] {
            failures.extend(in_parallel(phase, jobs, threads, |i| {
                let cell = &exp.cells[i];
                eprintln!("cell {}/{}: {}", i + 1, exp.cells.len(), cell.label());
                exp.run_cell(i, device.clone(), &mut Silent).err().map(|e| format!("{}: {e:#}", cell.dir.display()))
            }));
        }
    }
    if !failures.is_empty() {
        bail!("{} cell(s) failed (finished cells are kept; rerun to retry):\n{}", failures.len(), failures.join("\n"));
    }
    Ok(())
}

/// Calls `work` on every item, `jobs` at a time on as many workers (no more than there are
/// items), each worker taking the next item as it finishes one; returns what the calls
/// returned (`Some`: a failure), in the order they finished.
///
/// Each worker runs its items inside a rayon pool of its own with `threads` threads, so the
/// CPU kernels of one item never wait for another's: in rayon's one global pool the jobs'
/// kernels queued for the same threads (with `RAYON_NUM_THREADS=1`, two jobs took turns on one
/// thread and each ran at about half its speed).
fn in_parallel<F>(items: Vec<usize>, jobs: usize, threads: usize, work: F) -> Vec<String>
where
    F: Fn(usize) -> Option<String> + Sync,
{
    let workers = jobs.min(items.len());
    let queue = Mutex::new(items.into_iter());
    let failures = Mutex::new(Vec::new());
    let fail = |failure: String| failures.lock().expect("no poisoned lock").push(failure);
    std::thread::scope(|s| {
        for worker in 0..workers {
            let (queue, work, fail) = (&queue, &work, &fail);
            s.spawn(move || {
                let pool = match rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .thread_name(move |t| format!("job-{worker}-kernel-{t}"))
                    .build()
                {
                    Ok(pool) => pool,
                    Err(e) => {
                        return fail(format!(
                            "job {worker}: no kernel threads ({e}); its cells were left to the other jobs"
                        ));
                    }
                };
                loop {
                    // The queue is locked only to take an item, never while one is worked on.
                    let next = queue.lock().expect("no poisoned lock").next();
                    let Some(i) = next else { break };
                    if let Some(failure) = pool.install(|| work(i)) {
                        fail(failure);
                    }
                }
            });
        }
    });
    failures.into_inner().expect("no poisoned lock")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::time::{Duration, Instant};

    /// Marks one more call active, waits (up to 10 s) until `most` has seen two at once, and
    /// marks it done.
    fn wait_for_a_second(active: &AtomicUsize, most: &AtomicUsize) {
        let now = active.fetch_add(1, Ordering::SeqCst) + 1;
        most.fetch_max(now, Ordering::SeqCst);
        let start = Instant::now();
        while most.load(Ordering::SeqCst) < 2 && start.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(1));
        }
        active.fetch_sub(1, Ordering::SeqCst);
    }

    /// `--jobs 2` works on two cells at once: each call waits until the other worker has
    /// started one too, so one worker at a time would record a most of 1.
    #[test]
    fn jobs_run_at_the_same_time_and_every_item_once() {
        let (active, most, done) = (AtomicUsize::new(0), AtomicUsize::new(0), Mutex::new(Vec::new()));
        let failures = in_parallel((0..6).collect(), 2, 1, |i| {
            wait_for_a_second(&active, &most);
            done.lock().unwrap().push(i);
            (i % 3 == 0).then(|| format!("item {i}"))
        });
        assert_eq!(most.load(Ordering::SeqCst), 2, "the workers took turns instead of working at once");
        let mut done = done.into_inner().unwrap();
        done.sort();
        assert_eq!(done, (0..6).collect::<Vec<_>>());
        let mut failures = failures;
        failures.sort();
        assert_eq!(failures, ["item 0", "item 3"]);
    }

    /// Each job's kernels run on rayon threads of its own: with one kernel thread per job, a
    /// kernel task of each job waits inside rayon until the other job's is running too, which
    /// jobs sharing one kernel thread (rayon's global pool under `RAYON_NUM_THREADS=1`) could
    /// never see; and a job's pool has the threads it was given.
    #[test]
    fn each_job_runs_its_kernels_on_threads_of_its_own() {
        let (active, most) = (AtomicUsize::new(0), AtomicUsize::new(0));
        let failures = in_parallel((0..2).collect(), 2, 1, |_| {
            let (on_a_worker, ()) = rayon::join(
                || {
                    wait_for_a_second(&active, &most);
                    rayon::current_thread_index().is_some()
                },
                || (),
            );
            (!on_a_worker || rayon::current_num_threads() != 1).then(|| "not on its own kernel thread".to_string())
        });
        assert!(failures.is_empty(), "{failures:?}");
        assert_eq!(most.load(Ordering::SeqCst), 2, "the jobs' kernels took turns on shared threads");
        let sizes = Mutex::new(Vec::new());
        in_parallel((0..4).collect(), 2, 3, |_| {
            sizes.lock().unwrap().push(rayon::current_num_threads());
            None
        });
        assert_eq!(sizes.into_inner().unwrap(), [3, 3, 3, 3]);
    }

    #[test]
    fn the_kernel_threads_are_shared_out_among_the_jobs() {
        assert_eq!(threads_per_job(2, 1), 2);
        assert_eq!(threads_per_job(2, 2), 1);
        assert_eq!(threads_per_job(1, 2), 1, "at least one each");
        assert_eq!(threads_per_job(16, 4), 4);
        assert_eq!(threads_per_job(16, 3), 5);
        assert_eq!(threads_per_job(8, 0), 8, "no jobs read as one");
    }
}
