//! Keyframe selection + in-between reconstruction of a motion, and the use
//! case that runs it on the heavy pool.

use super::input::{prefix, MotionInput};
use super::{auth, ApiError, Choreo};
use crate::features::smpl24_at_60;
use crate::keyframes::inbetween::{self, BezierOffsets};
use crate::keyframes::metrics::{beat_alignment, motion_beats, mse, per_frame_error};
use crate::keyframes::{beat_frames, dp, even, from_peaks, position_curve, SegmentCost};
use crate::motion::{Motion, MotionError};
use serde::Serialize;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Select {
    Even,
    Onset,
    Percussive,
    Nmfd,
    Dp,
}

impl Select {
    pub fn parse(s: &str) -> Option<Select> {
        Some(match s {
            "even" => Select::Even,
            "onset" => Select::Onset,
            "percussive" => Select::Percussive,
            "nmfd" => Select::Nmfd,
            "dp" => Select::Dp,
            _ => return None,
        })
    }
    pub fn name(self) -> &'static str {
        match self {
            Select::Even => "even",
            Select::Onset => "onset",
            Select::Percussive => "percussive",
            Select::Nmfd => "nmfd",
            Select::Dp => "dp",
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Inbetween {
    Slerp,
    Bezier,
    /// Catmull-Rom through the keyframes alone.
    CatmullRom,
    /// Bézier with control points averaged over training data.
    BezierAverage(#[serde(skip)] BezierOffsets),
    /// SLERP plus the residual of a trained model (thesis 001 §3.5.3).
    Learned(#[serde(skip)] LearnedModel),
}

/// A loaded in-betweener (equal when it is the same one).
#[derive(Clone, Debug)]
pub struct LearnedModel(pub std::sync::Arc<crate::lm::inbetween::Inbetweener>);

impl PartialEq for LearnedModel {
    fn eq(&self, other: &Self) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

impl Inbetween {
    pub fn name(&self) -> &'static str {
        match self {
            Inbetween::Slerp => "slerp",
            Inbetween::Bezier => "bezier",
            Inbetween::CatmullRom => "catmull-rom",
            Inbetween::BezierAverage(_) => "bezier-avg",
            Inbetween::Learned(_) => "learned",
        }
    }
}

/// Where the music comes from.
#[derive(Clone, Debug)]
pub enum Music {
    None,
    /// A metronome at this tempo: its onsets are exactly the beats.
    Bpm(f64),
    /// Analysed audio, 60 feature frames a second, frame-aligned with the
    /// motion from its first frame.
    Audio(Box<crate::audio::MusicFeatures>),
}

/// Onset peaks within this many frames (50 ms at 60 fps) of either end
/// are not keyframe candidates (thesis 001 §3.4.2's guard).
pub const PEAK_GUARD: usize = 3;

/// The onset-like curve and its peaks (motion length, the clip's frames) a
/// music-based strategy reads: a metronome's beats for `onset` with a BPM,
/// or the analysed audio's onset, percussive-onset or NMFD curve.
fn onset_curve(
    music: &Music,
    select: Select,
    n: usize,
    fps: f64,
) -> Result<(Vec<f64>, Vec<usize>), MotionError> {
    let bad = |reason: String| MotionError::invalid("keyframes", "music", reason);
    let fit =
        |c: &[f64]| -> Vec<f64> { (0..n).map(|i| c.get(i).copied().unwrap_or(0.0)).collect() };
    let (curve, peaks) = match (music, select) {
        (Music::Bpm(bpm), Select::Onset) => {
            let beats = beat_frames(*bpm, fps, n)?;
            let mut curve = vec![0.0; n];
            beats.iter().for_each(|&b| curve[b] = 1.0);
            (curve, beats)
        }
        (Music::Audio(_), _) if (fps - crate::audio::FEATURE_FPS).abs() > 1e-9 => {
            return Err(MotionError::invalid(
                "keyframes",
                "fps",
                "music-based selection needs the clip at 60 fps",
            ))
        }
        (Music::Audio(f), Select::Onset) => (fit(&f.onset), f.peaks.clone()),
        (Music::Audio(f), Select::Percussive) => {
            (fit(&f.percussive_onset), f.percussive_peaks.clone())
        }
        (Music::Audio(f), Select::Nmfd) => (fit(&f.nmfd), f.nmfd_peaks.clone()),
        (_, Select::Onset) => return Err(bad(
            "onset selection needs music: give --music FILE or --bpm (a metronome at that tempo)"
                .into(),
        )),
        _ => {
            return Err(bad(format!(
                "{} selection needs an audio file (--music)",
                select.name()
            )))
        }
    };
    if curve.iter().all(|&v| v == 0.0) {
        return Err(bad(
            "the music has no onsets over the clip (is it silent?)".into()
        ));
    }
    Ok((curve, peaks.into_iter().filter(|&p| p < n).collect()))
}

#[derive(Clone, Debug)]
pub struct KeyframeRequest {
    pub select: Select,
    pub inbetween: Inbetween,
    pub count: usize,
    pub music: Music,
}

#[derive(Clone, Debug, Serialize)]
pub struct KeyframeReport {
    pub keyframes: Vec<usize>,
    /// Eq. 2.8 on FK joint positions, m².
    pub mse: f64,
    /// Per frame, mean over joints of the squared position error, m².
    pub per_frame_error: Vec<f64>,
    pub frames: usize,
    pub fps: f64,
    pub select: Select,
    pub inbetween: String,
    /// Beat alignment (σ = 3 frames) of the original and the rebuilt clip
    /// against the music's beats (onset peaks, or the metronome's beats).
    pub beat_alignment: Option<BeatAlignment>,
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct BeatAlignment {
    /// Mean over music beats of exp(−d²/2σ²) to the nearest kinematic beat.
    pub original_music_to_motion: f64,
    pub rebuilt_music_to_motion: f64,
    /// Mean over kinematic beats of the same, to the nearest music beat.
    pub original_motion_to_music: f64,
    pub rebuilt_motion_to_music: f64,
}

/// The music's beats over `n` frames at 60 fps, if there is music.
fn music_beats(music: &Music, n: usize) -> Option<Vec<usize>> {
    match music {
        Music::None => None,
        Music::Bpm(b) => beat_frames(*b, 60.0, n).ok(),
        Music::Audio(f) => Some(f.peaks.iter().copied().filter(|&p| p < n).collect()),
    }
}

/// Keyframes of a (SMPL-24, 60 fps) clip by a strategy.
pub fn select_keyframes(
    m: &Motion,
    select: Select,
    count: usize,
    music: &Music,
) -> Result<Vec<usize>, MotionError> {
    let n = m.frames();
    match select {
        Select::Even => even(n, count),
        Select::Dp => {
            let p = m.positions();
            let cost = SegmentCost::new(position_curve(&p), 3 * m.joints());
            Ok(dp(&cost, count, None)?.0)
        }
        Select::Onset | Select::Percussive | Select::Nmfd => {
            let (curve, peaks) = onset_curve(music, select, n, m.fps)?;
            from_peaks(&curve, &peaks, count, PEAK_GUARD)
        }
    }
}

/// Rebuild a clip's in-betweens from keyframes.
pub fn rebuild(m: &Motion, keys: &[usize], how: &Inbetween) -> Result<Motion, MotionError> {
    match how {
        Inbetween::Slerp => inbetween::slerp(m, keys),
        Inbetween::Bezier => inbetween::bezier(m, keys),
        Inbetween::CatmullRom => inbetween::catmull_rom(m, keys),
        Inbetween::BezierAverage(off) => off.apply(m, keys),
        Inbetween::Learned(model) => model.0.rebuild(m, keys),
    }
}

/// Select keyframes of any motion (brought to SMPL-24 at 60 fps) and rebuild
/// it; returns the rebuilt motion and the report.
pub fn reconstruct(
    m: &Motion,
    req: &KeyframeRequest,
) -> Result<(Motion, KeyframeReport), MotionError> {
    let m = smpl24_at_60(m)?;
    let keys = select_keyframes(&m, req.select, req.count, &req.music)?;
    let r = rebuild(&m, &keys, &req.inbetween)?;
    let (pa, pb) = (m.positions(), r.positions());
    let beat_alignment = music_beats(&req.music, m.frames()).and_then(|mb| {
        let j = m.joints();
        let (o, b) = (
            beat_alignment(&mb, &motion_beats(&pa, j), 3.0)?,
            beat_alignment(&mb, &motion_beats(&pb, j), 3.0)?,
        );
        Some(BeatAlignment {
            original_music_to_motion: o.0,
            rebuilt_music_to_motion: b.0,
            original_motion_to_music: o.1,
            rebuilt_motion_to_music: b.1,
        })
    });
    let report = KeyframeReport {
        beat_alignment,
        mse: mse(&pa, &pb),
        per_frame_error: per_frame_error(&pa, &pb, m.joints()),
        frames: m.frames(),
        fps: m.fps,
        keyframes: keys,
        select: req.select,
        inbetween: req.inbetween.name().to_string(),
    };
    Ok((r, report))
}

pub struct KeyframesParams {
    pub motion: MotionInput,
    pub count: usize,
    pub select: String,
    pub inbetween: String,
    pub bpm: f64,
    pub music: Option<(String, Vec<u8>)>,
}

pub async fn keyframes(
    state: &Choreo,
    p: KeyframesParams,
    who: &auth::Principal,
) -> Result<(Motion, KeyframeReport), ApiError> {
    let m = state.resolve("motion", p.motion, who).await?;
    let select = match p.select.as_str() {
        "" => Select::Dp,
        s => Select::parse(s).ok_or_else(|| {
            ApiError::invalid(
                "select",
                format!("'{s}' is not even, onset, percussive, nmfd or dp"),
            )
        })?,
    };
    let inbetween = match p.inbetween.as_str() {
        "" | "slerp" => Inbetween::Slerp,
        "bezier" => Inbetween::Bezier,
        "catmull-rom" => Inbetween::CatmullRom,
        "learned" => Inbetween::Learned(LearnedModel(state.inbetweener.clone().ok_or_else(
            || {
                ApiError::Unavailable(
                    "no learned in-betweener is installed (set --inbetweener)".into(),
                )
            },
        )?)),
        o => {
            return Err(ApiError::invalid(
                "inbetween",
                format!("'{o}' is not slerp, bezier, catmull-rom or learned"),
            ))
        }
    };
    if p.music.is_some() && p.bpm != 0.0 {
        return Err(ApiError::invalid(
            "bpm",
            "give music or bpm, not both (the music's own beats set the grid)",
        ));
    }
    let (count, bpm, music) = (p.count, p.bpm, p.music);
    state
        .heavy("keyframes", move || {
            let music = match (music, bpm) {
                (Some((name, bytes)), _) => {
                    let ext = std::path::Path::new(&name)
                        .extension()
                        .and_then(|e| e.to_str())
                        .map(|e| e.to_ascii_lowercase());
                    let a = crate::audio::decode(bytes, &name, ext.as_deref())
                        .map_err(|e| prefix("music", e.into()))?;
                    let (_, f) =
                        crate::audio::analyse(&a, &name).map_err(|e| prefix("music", e.into()))?;
                    Music::Audio(Box::new(f))
                }
                (None, b) if b != 0.0 => Music::Bpm(b),
                _ => Music::None,
            };
            let req = KeyframeRequest {
                select,
                inbetween,
                count,
                music,
            };
            Ok(reconstruct(&m, &req)?)
        })
        .await
}
