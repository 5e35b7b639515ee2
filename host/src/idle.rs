//! Work for the cores the capture leaves idle.
//!
//! A simulated capture keeps the cores busy only while a pose renders; between
//! poses they wait on the rig and the link. Work the later stages will need
//! anyway can run then, on threads at the lowest scheduling priority, so it
//! takes only the time the capture leaves.

use std::thread::JoinHandle;

/// Runs `job` on a pool of `threads` threads at the lowest priority (nice
/// 19, Linux); the handle joins it. Where priorities cannot be lowered the
/// job still runs, at normal priority.
pub fn in_idle_time<F>(threads: usize, job: F) -> std::io::Result<JoinHandle<()>>
where
    F: FnOnce() + Send + 'static,
{
    std::thread::Builder::new()
        .name("idle-work".into())
        .spawn(move || {
            lower_priority();
            match rayon::ThreadPoolBuilder::new()
                .num_threads(threads.max(1))
                .thread_name(|i| format!("idle-work-{i}"))
                .start_handler(|_| lower_priority())
                .build()
            {
                Ok(pool) => pool.install(job),
                Err(_) => job(),
            }
        })
}

/// This thread to nice 19: on Linux a thread's priority is its own.
fn lower_priority() {
    #[cfg(target_os = "linux")]
    {
        let tid = nix::unistd::gettid().as_raw();
        // SAFETY: setpriority only reads its arguments; a failure (a
        // sandbox forbidding it) leaves the priority as it was.
        unsafe {
            nix::libc::setpriority(nix::libc::PRIO_PROCESS, tid as nix::libc::id_t, 19);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_job_runs_on_its_pool_at_the_lowest_priority() {
        let (tx, rx) = std::sync::mpsc::channel();
        in_idle_time(2, move || {
            let in_pool = rayon::current_num_threads();
            #[cfg(target_os = "linux")]
            // SAFETY: getpriority only reads its arguments.
            let nice = unsafe {
                nix::libc::getpriority(
                    nix::libc::PRIO_PROCESS,
                    nix::unistd::gettid().as_raw() as nix::libc::id_t,
                )
            };
            #[cfg(not(target_os = "linux"))]
            let nice = 19;
            tx.send((in_pool, nice)).unwrap();
        })
        .unwrap()
        .join()
        .unwrap();
        let (in_pool, nice) = rx.recv().unwrap();
        assert_eq!(in_pool, 2);
        assert_eq!(nice, 19);
    }
}
