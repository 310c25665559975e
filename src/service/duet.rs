//! The live duet: a performer's frames in, the model's full-body frames
//! out, one worker permit held for the session's life. REST's WebSocket
//! and gRPC's `Duet` both run [`duet`].

use super::generate::{model, StreamFrame};
use super::{ApiError, Choreo};
use crate::lm::Sampling;
use crate::motion::{Labels, Motion};
use std::time::Instant;
use tokio::sync::mpsc;

/// A live duet ([`crate::lm::duet::Duet`]) holding a worker permit for
/// its whole life.
pub struct DuetSession {
    duet: crate::lm::duet::Duet,
    _permit: tokio::sync::OwnedSemaphorePermit,
}

impl DuetSession {
    pub fn open(
        state: &Choreo,
        labels: &Labels,
        joints: &[String],
        (mut sampling, named): (Sampling, super::generate::Named),
    ) -> Result<DuetSession, ApiError> {
        let session = model(state)?;
        session.fill_defaults(labels, &mut sampling, named);
        let duet = crate::lm::duet::Duet::new(session, labels, joints, sampling)?;
        let permit = state
            .workers
            .clone()
            .try_acquire_owned()
            .map_err(|_| ApiError::Busy("every worker is busy; retry the duet later".into()))?;
        Ok(DuetSession {
            duet,
            _permit: permit,
        })
    }

    /// One performer frame in (a one-frame motion at the model's frame
    /// rate), one full-body frame out.
    pub fn step(&mut self, frame: Motion) -> Result<StreamFrame, ApiError> {
        let t0 = Instant::now();
        let f = self.duet.step(frame)?;
        Ok(StreamFrame {
            index: f.index,
            rotations: f.rotations,
            translation: f.translation,
            latency_ms: t0.elapsed().as_secs_f64() * 1e3,
        })
    }
}

/// Runs a duet: performer frames (each a one-frame motion, or the
/// transport's error for a frame it could not read) go in on the sender,
/// full-body frames come out of the receiver, in order. Each step runs on
/// the blocking pool. The loop ends when the sender is dropped (the
/// performer stopped), when the receiver is dropped (the client went away),
/// or after the first error, which is sent before it ends. REST's
/// WebSocket and gRPC's `Duet` both run this loop.
pub fn duet(
    mut session: DuetSession,
) -> (
    mpsc::Sender<Result<Motion, ApiError>>,
    mpsc::Receiver<Result<StreamFrame, ApiError>>,
) {
    let (in_tx, mut in_rx) = mpsc::channel::<Result<Motion, ApiError>>(64);
    let (out_tx, out_rx) = mpsc::channel(64);
    tokio::spawn(async move {
        while let Some(frame) = in_rx.recv().await {
            let out = match frame {
                Ok(m) => {
                    let stepped = tokio::task::spawn_blocking(move || {
                        let r = session.step(m);
                        (session, r)
                    })
                    .await;
                    match stepped {
                        Ok((s, r)) => {
                            session = s;
                            r
                        }
                        // A failed step takes the session with it: say so, end the duet.
                        Err(e) => {
                            let _ = out_tx
                                .send(Err(ApiError::Internal(format!("duet step failed: {e}"))))
                                .await;
                            break;
                        }
                    }
                }
                Err(e) => Err(e),
            };
            let failed = out.is_err();
            if out_tx.send(out).await.is_err() || failed {
                break;
            }
        }
    });
    (in_tx, out_rx)
}
