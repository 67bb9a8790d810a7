//! Work spread over a pool of workers that each own what they work with (an
//! ONNX Runtime session each), while the store is read and written on the
//! calling thread only, in item order: the learned stages run this way.

use std::collections::BTreeMap;
use std::sync::{mpsc, Mutex};

use crate::{Cancel, PipelineError};

/// The cores this process may use.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// How many workers `requested` means: 0 is one per core, as many as the
/// available memory holds at `mib_each` a worker (at least one).
pub fn count(requested: usize, mib_each: f64) -> usize {
    match requested {
        0 => {
            let cores = cores();
            let fit = crate::memory::available_mib().map_or(cores, |mib| (mib / mib_each) as usize);
            cores.min(fit).max(1)
        }
        n => n,
    }
}

/// Runs `work` on items `0..items`, one item at a time on each of `workers`
/// (one thread each). On the calling thread, with `store` (what both read and
/// write: the store): `read(store, i)` gives item `i`'s input, in order, a
/// little ahead of the workers; `write(store, i, output)` takes each output in
/// item order (so what is stored does not depend on the number of workers).
/// Stops reading at the first error or when `cancel` is set, writes the
/// outputs before it that were in flight, and returns that error.
pub fn in_order<S: ?Sized, W, I, O>(
    store: &mut S,
    workers: &mut [W],
    items: usize,
    mut read: impl FnMut(&S, usize) -> Result<I, PipelineError>,
    work: impl Fn(&mut W, usize, I) -> Result<O, PipelineError> + Sync,
    mut write: impl FnMut(&mut S, usize, O) -> Result<(), PipelineError>,
    cancel: &Cancel,
) -> Result<(), PipelineError>
where
    W: Send,
    I: Send,
    O: Send,
{
    assert!(!workers.is_empty() || items == 0, "work without workers");
    let ahead = 2 * workers.len();
    let (job_sender, jobs) = mpsc::channel::<(usize, I)>();
    let (done_sender, done) = mpsc::channel::<(usize, Result<O, PipelineError>)>();
    let jobs = Mutex::new(jobs);
    std::thread::scope(|scope| {
        for worker in workers.iter_mut() {
            let (jobs, done_sender, work) = (&jobs, done_sender.clone(), &work);
            scope.spawn(move || loop {
                let job = jobs.lock().unwrap_or_else(|e| e.into_inner()).recv();
                let Ok((index, input)) = job else { break };
                // The receiver outlives the workers.
                let _ = done_sender.send((index, work(worker, index, input)));
            });
        }
        drop(done_sender);
        let (mut next, mut written, mut in_flight) = (0, 0, 0);
        let (mut pending, mut failure) = (BTreeMap::new(), None);
        loop {
            while failure.is_none() && next < items && in_flight < ahead {
                match cancel.check().and_then(|()| read(store, next)) {
                    Ok(input) => {
                        let _ = job_sender.send((next, input));
                        (next, in_flight) = (next + 1, in_flight + 1);
                    }
                    Err(error) => failure = Some(error),
                }
            }
            if in_flight == 0 {
                break;
            }
            let Ok((index, output)) = done.recv() else { break };
            in_flight -= 1;
            pending.insert(index, output);
            while let Some(output) = pending.remove(&written) {
                match output.and_then(|output| write(store, written, output)) {
                    Ok(()) => written += 1,
                    Err(error) => {
                        // Later outputs still in flight are awaited, not written.
                        failure.get_or_insert(error);
                    }
                }
            }
        }
        drop(job_sender);
        failure.map_or(Ok(()), Err)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_are_written_in_item_order_whatever_the_workers() {
        for workers in [1, 2, 5] {
            let mut pool: Vec<usize> = vec![0; workers];
            let mut written = Vec::new();
            in_order(
                &mut written,
                &mut pool,
                20,
                |_, i| Ok(i * 10),
                |done, i, input| {
                    *done += 1;
                    // Later items finish first.
                    std::thread::sleep(std::time::Duration::from_millis(20 - i as u64));
                    Ok(input + 1)
                },
                |written, i, output| {
                    written.push((i, output));
                    Ok(())
                },
                &Cancel::new(),
            )
            .unwrap();
            assert_eq!(written, (0..20).map(|i| (i, i * 10 + 1)).collect::<Vec<_>>());
            assert_eq!(pool.iter().sum::<usize>(), 20);
        }
    }

    #[test]
    fn a_failure_stops_reading_and_keeps_what_came_before() {
        let mut pool = vec![(), ()];
        let mut written = Vec::new();
        let result = in_order(
            &mut written,
            &mut pool,
            50,
            |_, i| Ok(i),
            |_, i, _| match i {
                7 => Err(PipelineError::Cancelled),
                i => Ok(i),
            },
            |written, i, _| {
                written.push(i);
                Ok(())
            },
            &Cancel::new(),
        );
        assert!(matches!(result, Err(PipelineError::Cancelled)));
        assert_eq!(written, (0..7).collect::<Vec<_>>());
    }

    #[test]
    fn cancelled_work_stops_before_reading_more() {
        let cancel = Cancel::new();
        let mut pool = vec![()];
        let mut read = 0;
        let result = in_order(
            &mut (),
            &mut pool,
            50,
            |(), i| {
                read += 1;
                if i == 3 {
                    cancel.cancel();
                }
                Ok(i)
            },
            |_, i, _| Ok(i),
            |(), _, _| Ok(()),
            &cancel,
        );
        assert!(matches!(result, Err(PipelineError::Cancelled)));
        assert_eq!(read, 4);
    }
}
