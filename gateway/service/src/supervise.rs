//! A job that can never jam its machine: a panic inside it ends it with its message, and
//! a job still running [`CANCEL_GRACE`](crate::worker::CANCEL_GRACE) after its stop was
//! requested is dropped.

use futures_util::FutureExt;
use std::panic::AssertUnwindSafe;
use std::time::Duration;
use tokio::sync::watch;

/// The text of a panic's payload.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

/// How a supervised job ended.
#[derive(Debug, PartialEq)]
pub(crate) enum Supervised<T> {
    Ended(T),
    /// It panicked: the panic's message.
    Panicked(String),
    /// It did not end within the grace period after its stop was requested: dropped.
    Dropped,
}

/// Runs `job` so that it can never jam its machine: a panic inside it is caught (the
/// job ends, the worker goes on); once `stop_requested` completes the job's own stop
/// signal (`stop_tx`) is raised, and a job still running `grace` later is dropped.
pub(crate) async fn supervise<T>(
    job: impl std::future::Future<Output = T>,
    stop_requested: impl std::future::Future<Output = ()>,
    stop_tx: watch::Sender<bool>,
    grace: Duration,
) -> Supervised<T> {
    let job = AssertUnwindSafe(job).catch_unwind();
    tokio::pin!(job);
    tokio::pin!(stop_requested);
    let mut stopping = false;
    loop {
        tokio::select! {
            r = &mut job => return match r {
                Ok(v) => Supervised::Ended(v),
                Err(payload) => Supervised::Panicked(panic_message(payload.as_ref())),
            },
            _ = &mut stop_requested, if !stopping => {
                stopping = true;
                let _ = stop_tx.send(true);
            }
            _ = tokio::time::sleep(grace), if stopping => return Supervised::Dropped,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::worker::CANCEL_GRACE;

    fn stop_pair() -> (watch::Sender<bool>, watch::Receiver<bool>) {
        watch::channel(false)
    }

    #[tokio::test]
    async fn a_panicking_job_ends_with_its_message() {
        let (tx, _rx) = stop_pair();
        let job = async {
            if tx.is_closed() {
                return 1;
            }
            panic!("boom in a procedure")
        };
        let (tx2, _rx2) = stop_pair();
        let r = supervise(job, std::future::pending(), tx2, CANCEL_GRACE).await;
        assert_eq!(r, Supervised::Panicked("boom in a procedure".into()));
    }

    #[tokio::test]
    async fn a_job_that_honours_its_stop_ends_by_itself() {
        let (tx, mut rx) = stop_pair();
        let job = async move {
            let _ = rx.wait_for(|s| *s).await;
            "stopped"
        };
        let r = supervise(job, async {}, tx, CANCEL_GRACE).await;
        assert_eq!(r, Supervised::Ended("stopped"));
    }

    // The paused clock advances only when every task waits: no wall time passes.
    #[tokio::test(start_paused = true)]
    async fn a_job_that_ignores_its_stop_is_dropped_after_the_grace() {
        let (tx, _rx) = stop_pair();
        let started = tokio::time::Instant::now();
        let r = supervise(std::future::pending::<()>(), async {}, tx, CANCEL_GRACE).await;
        assert_eq!(r, Supervised::Dropped);
        assert_eq!(started.elapsed(), CANCEL_GRACE);
    }

    #[tokio::test(start_paused = true)]
    async fn a_job_is_never_dropped_without_a_stop() {
        let (tx, _rx) = stop_pair();
        let job = async {
            tokio::time::sleep(CANCEL_GRACE * 10).await;
            7
        };
        let r = supervise(job, std::future::pending(), tx, CANCEL_GRACE).await;
        assert_eq!(r, Supervised::Ended(7));
    }
}
