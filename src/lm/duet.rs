//! A live duet, model side: the performer's prompt joints come in frame by
//! frame, the model answers each with a full-body frame. The server wraps
//! it with a worker permit (`service::duet::DuetSession`); `choreo bench model
//! --duet FILE` times it on each runtime.

use super::model::{MotionGenerator, MotionModel};
use super::{forced_frames, prompt_slots, FrameDecoder, LmError, Sampling};
use crate::motion::{Labels, Motion};

pub struct Duet {
    model: MotionModel,
    gen: MotionGenerator,
    slots: Vec<bool>,
    prev: Option<Motion>,
    /// The lowest floor seen so far (heights are tokenized against it).
    floor: Option<f64>,
    dec: FrameDecoder,
    pub frames: usize,
}

/// One answered frame: axis-angle per joint of the model's skeleton and
/// the root translation.
pub struct DuetFrame {
    pub index: usize,
    pub rotations: Vec<[f64; 3]>,
    pub translation: [f64; 3],
}

impl Duet {
    /// A duet in which the performer drives `joints` (the model's joint
    /// names, any case; at least one).
    pub fn new(
        model: MotionModel,
        labels: &Labels,
        joints: &[String],
        sampling: Sampling,
    ) -> Result<Duet, LmError> {
        if joints.is_empty() {
            return Err(LmError::invalid(
                "request",
                "prompt_joints",
                "a duet needs the joints the performer drives",
            ));
        }
        let slots = prompt_slots(model.vocabulary(), joints)?;
        let gen = model.generator(labels, &[], sampling)?;
        Ok(Duet {
            model,
            gen,
            slots,
            prev: None,
            floor: None,
            dec: FrameDecoder::new(),
            frames: 0,
        })
    }

    /// One performer frame in (a one-frame motion at the model's frame
    /// rate), one full-body frame out.
    pub fn step(&mut self, frame: Motion) -> Result<DuetFrame, LmError> {
        let vocab = self.model.vocabulary();
        if frame.frames() != 1 {
            return Err(LmError::invalid(
                "request",
                "frame",
                format!("{} frames; send one frame a message", frame.frames()),
            ));
        }
        if (frame.fps - vocab.fps).abs() > 1e-6 {
            return Err(LmError::invalid(
                "request",
                "frame.fps",
                format!(
                    "{}; a duet runs at the model's {} fps",
                    frame.fps, vocab.fps
                ),
            ));
        }
        // Velocities need the previous frame: encode the pair, keep the last.
        let pair = match &self.prev {
            Some(p) if p.skeleton.names == frame.skeleton.names => {
                let mut rot = p.rotations.clone();
                rot.extend_from_slice(&frame.rotations);
                Motion::new(
                    "duet",
                    frame.fps,
                    frame.skeleton.clone(),
                    vec![p.trans[0], frame.trans[0]],
                    rot,
                    Labels::new(),
                )?
            }
            _ => frame.clone(),
        };
        let (tokens, floor) = vocab.encode_motion_on_floor(&pair, self.floor)?;
        self.floor = Some(floor);
        let fl = vocab.frame_len();
        let last = &tokens[tokens.len() - fl..];
        let forced = forced_frames(last, &self.slots).pop().unwrap_or_default();
        let out = self.gen.next_frame(&forced)?;
        let (rotations, translation) = self.dec.decode(vocab, &out)?;
        self.prev = Some(frame);
        let index = self.frames;
        self.frames += 1;
        Ok(DuetFrame {
            index,
            rotations,
            translation,
        })
    }
}
