//! Reading music: decoding (WAV, Ogg Vorbis, MP3 through symphonia),
//! mixing to mono, and resampling with a Kaiser-windowed sinc.

use super::*;

pub(super) fn bad(file: &str, field: &str, reason: impl Into<String>) -> MotionError {
    MotionError::invalid(file, field, reason)
}

/// Mono audio.
#[derive(Clone, Debug)]
pub struct Audio {
    pub sample_rate: u32,
    pub samples: Vec<f32>,
    /// Channels in the source before the mono mix.
    pub channels: usize,
}

impl Audio {
    pub fn seconds(&self) -> f64 {
        self.samples.len() as f64 / self.sample_rate as f64
    }
}

/// Decode a WAV / Ogg Vorbis / MP3 file's bytes (the extension, if any, is
/// a hint) to mono f32. The decoder library panics on some malformed
/// headers (a zero sample rate, say); such a panic is caught and reported
/// as a bad file.
pub fn decode(bytes: Vec<u8>, name: &str, extension: Option<&str>) -> Result<Audio, MotionError> {
    std::panic::catch_unwind(|| decode_inner(bytes, name, extension)).unwrap_or_else(|p| {
        let why = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "malformed stream".into());
        Err(bad(name, "audio", format!("cannot decode: {why}")))
    })
}

fn decode_inner(bytes: Vec<u8>, name: &str, extension: Option<&str>) -> Result<Audio, MotionError> {
    use symphonia::core::audio::SampleBuffer;
    use symphonia::core::codecs::{DecoderOptions, CODEC_TYPE_NULL};
    use symphonia::core::errors::Error;
    use symphonia::core::formats::FormatOptions;
    use symphonia::core::io::MediaSourceStream;
    use symphonia::core::meta::MetadataOptions;
    use symphonia::core::probe::Hint;
    if bytes.is_empty() {
        return Err(bad(name, "audio", "the file is empty"));
    }
    let mss = MediaSourceStream::new(Box::new(std::io::Cursor::new(bytes)), Default::default());
    let mut hint = Hint::new();
    if let Some(e) = extension {
        hint.with_extension(e);
    }
    let probed = symphonia::default::get_probe()
        .format(
            &hint,
            mss,
            &FormatOptions::default(),
            &MetadataOptions::default(),
        )
        .map_err(|e| {
            bad(
                name,
                "audio",
                format!("not a readable WAV, Ogg or MP3 file ({e})"),
            )
        })?;
    let mut format = probed.format;
    let track = format
        .tracks()
        .iter()
        .find(|t| t.codec_params.codec != CODEC_TYPE_NULL)
        .ok_or_else(|| bad(name, "audio", "no audio track"))?;
    let track_id = track.id;
    let mut decoder = symphonia::default::get_codecs()
        .make(&track.codec_params, &DecoderOptions::default())
        .map_err(|e| bad(name, "codec", format!("unsupported codec ({e})")))?;
    let mut rate = track.codec_params.sample_rate.unwrap_or(0);
    let mut channels = 0usize;
    let mut mono: Vec<f32> = Vec::new();
    let mut buf: Option<SampleBuffer<f32>> = None;
    loop {
        let packet = match format.next_packet() {
            Ok(p) => p,
            Err(Error::IoError(e)) if e.kind() == std::io::ErrorKind::UnexpectedEof => break,
            Err(Error::ResetRequired) => break,
            Err(e) => return Err(bad(name, "audio", format!("corrupt stream ({e})"))),
        };
        if packet.track_id() != track_id {
            continue;
        }
        let decoded = match decoder.decode(&packet) {
            Ok(d) => d,
            // A damaged packet is skipped, as players do.
            Err(Error::DecodeError(_)) => continue,
            Err(e) => return Err(bad(name, "audio", format!("cannot decode ({e})"))),
        };
        let spec = *decoded.spec();
        rate = spec.rate;
        channels = spec.channels.count().max(1);
        if buf
            .as_ref()
            .is_none_or(|b| b.capacity() < decoded.capacity() * channels)
        {
            buf = Some(SampleBuffer::new(decoded.capacity() as u64, spec));
        }
        let b = buf.as_mut().expect("allocated above");
        b.copy_interleaved_ref(decoded);
        for frame in b.samples().chunks(channels) {
            mono.push(frame.iter().sum::<f32>() / channels as f32);
        }
        if rate > 0 && mono.len() as f64 / rate as f64 > MAX_SECONDS {
            return Err(bad(name, "audio", format!("longer than {MAX_SECONDS} s")));
        }
    }
    if rate == 0 || !(1000..=768_000).contains(&rate) {
        return Err(bad(
            name,
            "sample_rate",
            format!("{rate} Hz is not a usable sample rate"),
        ));
    }
    if mono.is_empty() {
        return Err(bad(name, "audio", "no samples decoded"));
    }
    if mono.iter().any(|v| !v.is_finite()) {
        return Err(bad(name, "audio", "holds NaN or infinite samples"));
    }
    Ok(Audio {
        sample_rate: rate,
        samples: mono,
        channels,
    })
}

pub fn read(path: &std::path::Path) -> Result<Audio, MotionError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| MotionError::Io {
        file: name.clone(),
        error: e,
    })?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    decode(bytes, &name, ext.as_deref())
}

fn bessel_i0(x: f64) -> f64 {
    let (mut sum, mut term, mut k) = (1.0, 1.0, 1.0);
    while term > 1e-12 * sum {
        term *= (x / (2.0 * k)).powi(2);
        sum += term;
        k += 1.0;
    }
    sum
}

/// Band-limited resampling with a Kaiser-windowed sinc (32 zero crossings
/// at the lower rate, β = 8.6, cut-off at 95 % of the lower Nyquist).
pub fn resample(x: &[f32], from: u32, to: u32) -> Vec<f32> {
    if from == to || x.is_empty() {
        return x.to_vec();
    }
    let ratio = to as f64 / from as f64;
    let cutoff = ratio.min(1.0) * 0.95;
    let zeros = 32.0;
    let half = zeros / cutoff; // half-width in input samples
    let beta = 8.6;
    let i0b = bessel_i0(beta);
    // Tabulated kernel over [0, half], 512 points per input sample.
    let per = 512.0;
    let len = (half * per).ceil() as usize + 2;
    let table: Vec<f64> = (0..len)
        .map(|i| {
            let u = i as f64 / per;
            if u > half {
                return 0.0;
            }
            let s = if u == 0.0 {
                1.0
            } else {
                (std::f64::consts::PI * cutoff * u).sin() / (std::f64::consts::PI * cutoff * u)
            };
            let w = bessel_i0(beta * (1.0 - (u / half).powi(2)).max(0.0).sqrt()) / i0b;
            cutoff * s * w
        })
        .collect();
    let h = |u: f64| -> f64 {
        let p = u.abs() * per;
        let i = p as usize;
        if i + 1 >= len {
            return 0.0;
        }
        let f = p - i as f64;
        table[i] * (1.0 - f) + table[i + 1] * f
    };
    let n_out = ((x.len() as f64) * ratio).ceil() as usize;
    (0..n_out)
        .map(|n| {
            let t = n as f64 / ratio;
            let lo = (t - half).ceil().max(0.0) as usize;
            let hi = ((t + half).floor() as usize).min(x.len() - 1);
            let mut acc = 0.0;
            for (k, &v) in x.iter().enumerate().take(hi + 1).skip(lo) {
                acc += v as f64 * h(t - k as f64);
            }
            acc as f32
        })
        .collect()
}
