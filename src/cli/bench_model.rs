//! `choreo bench model`: a motion model's speed on one runtime (tract or
//! onnxruntime): step latencies, the whole-window forward, streaming frame
//! latency and real-time factor, and allocations per decoded token (the
//! binary's counting allocator); one JSON object, beside
//! `scripts/bench_frame_onnxruntime.py` and `scripts/bench_onnxruntime.py`.

use super::percentile;
use anyhow::Result;
use std::path::Path;
use std::time::Instant;

pub fn run(
    dir: &Path,
    engine: &choreo::lm::engine::Engine,
    repeats: usize,
    frames: usize,
    dump: Option<&Path>,
    duet: Option<(&Path, &[String])>,
    labels: &choreo::motion::Labels,
    json: bool,
) -> Result<()> {
    use choreo::lm::model::MotionModel;
    use choreo::lm::{Kv, Sampling};
    let t0 = Instant::now();
    let model = MotionModel::load_with(dir, engine)?;
    let load = t0.elapsed().as_secs_f64();
    let v = model.vocabulary().clone();
    // Whole-window forward (the flat model's one-step window).
    let mut window = serde_json::Value::Null;
    if let MotionModel::Flat(s) = &model {
        let cfg = s.config().clone();
        let (toks, pos) = choreo::lm::bench_window(&cfg, &v);
        s.step(&toks, &pos, Kv::empty(&cfg))?;
        let t1 = Instant::now();
        for _ in 0..repeats {
            s.step(&toks, &pos, Kv::empty(&cfg))?;
        }
        let per = t1.elapsed().as_secs_f64() / repeats as f64;
        if let Some(p) = dump {
            let a: Vec<i64> = pos.iter().map(|q| q.a).collect();
            let b: Vec<i64> = pos.iter().map(|q| q.b).collect();
            std::fs::write(
                p,
                serde_json::json!({"tokens": toks, "pos_a": a, "pos_b": b, "objective": cfg.objective, "n_layers": cfg.n_layers, "n_heads": cfg.n_heads, "d_head": cfg.d_head(), "inputs": s.manifest.inputs}).to_string(),
            )?;
        }
        window = serde_json::json!({
            "window_tokens": toks.len(),
            "window_forward_ms": per * 1e3,
            "forward_tokens_per_s": toks.len() as f64 / per,
        });
    }
    // The frame model: one global step (past 150 frames) and one local
    // (slot) step, each timed alone; the window forward is the global pass
    // over a whole context, as classification runs it.
    let mut steps = serde_json::Value::Null;
    let mut local_p50 = None;
    if let MotionModel::Frame(s) = &model {
        let n = (repeats * 50).max(200);
        let (mut g, mut l) = s.time_steps(150, n)?;
        let vals = vec![(v.bins / 2) as u32; s.config().slots * s.config().max_frames];
        s.classify(&vals)?;
        let t1 = Instant::now();
        let reps = repeats.clamp(1, 5);
        for _ in 0..reps {
            s.classify(&vals)?;
        }
        let per = t1.elapsed().as_secs_f64() / reps as f64;
        g.sort_by(f64::total_cmp);
        l.sort_by(f64::total_cmp);
        local_p50 = Some(percentile(&l, 0.5));
        // Four candidate frames' local steps side by side (the batch
        // `sampling.draws` 4 runs), per slot, where the graph can batch.
        let c = s.config();
        let mid = vec![(v.bins / 2) as u32; c.slots];
        let cands = vec![mid.clone(); 4];
        let h = s.state_after(&s.cond(&Default::default())?, &[mid.clone(), mid.clone()])?;
        let ctx = (Some(mid.as_slice()), Some(mid.as_slice()));
        let mut x4 = Vec::new();
        if s.batches() {
            for _ in 0..repeats.max(5) {
                let t = Instant::now();
                s.local_logits(&h, ctx, &cands, true)?;
                x4.push(t.elapsed().as_secs_f64() * 1e3 / c.slots as f64);
            }
            x4.sort_by(f64::total_cmp);
        }
        steps = serde_json::json!({
            "global_step_ms_p50": percentile(&g, 0.5),
            "local_step_ms_p50": local_p50,
            "local_step_x4_ms_p50": (!x4.is_empty()).then(|| percentile(&x4, 0.5)),
        });
        window = serde_json::json!({"window_frames": s.config().max_frames, "window_forward_ms": per * 1e3});
    }
    // Streaming: per-frame latency over `frames` frames (window slides).
    // Temperature 1, nothing cut, one candidate a frame.
    let g_sampling = Sampling {
        temperature: 1.0,
        seed: 1,
        ..Sampling::default()
    };
    let mut g = model.generator(&Default::default(), &[], g_sampling.clone())?;
    let mut lat = Vec::with_capacity(frames);
    let free = vec![None; v.frame_len()];
    let t2 = Instant::now();
    let allocs0 = crate::choreo_alloc::count();
    for _ in 0..frames {
        let t = Instant::now();
        g.next_frame(&free)?;
        lat.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let total = t2.elapsed().as_secs_f64();
    let allocs = (crate::choreo_alloc::count() - allocs0) as f64 / frames as f64;
    lat.sort_by(f64::total_cmp);
    let q = |p: f64| percentile(&lat, p);
    // The decode step: one sequential network step. For the frame model
    // that is a local (slot) step; the flat model's figure is a frame over
    // its 43 tokens.
    let decode = local_p50.unwrap_or(q(0.5) / v.frame_len() as f64);
    // The frame model again with 4 candidate frames a frame (`draws`, the
    // Bandai style default): four local passes a frame, one global step.
    let mut draws4 = serde_json::Value::Null;
    if let MotionModel::Frame(_) = &model {
        let four = Sampling {
            draws: 4,
            ..g_sampling.clone()
        };
        let g4 = model.generator(&Default::default(), &[], four)?;
        draws4 = stream(g4, frames, &free, v.fps)?;
    }
    // What a request with the labels and no sampling gets: the service's
    // recommended sampling with the model's defaults for the label kinds.
    let mut labelled = serde_json::Value::Null;
    if !labels.is_empty() {
        let mut s = Sampling::recommended(1);
        model.fill_defaults(labels, &mut s, Default::default());
        let g = model.generator(labels, &[], s.clone())?;
        labelled = stream(g, frames, &free, v.fps)?;
        labelled["labels"] = serde_json::json!(labels);
        labelled["sampling"] = choreo::eval::generate::sampling_name(&s).into();
    }
    // A duet: a real motion as the performer, one frame in, one out.
    let mut duet_json = serde_json::Value::Null;
    if let Some((file, joints)) = duet {
        let m = choreo::motion::io::read_path(file, &Default::default())?
            .motion
            .resample(v.fps)?;
        let n = frames.min(m.frames());
        let mut d = choreo::lm::duet::Duet::new(
            model.clone(),
            &Default::default(),
            joints,
            Sampling {
                top_p: 0.95,
                ..g_sampling.clone()
            },
        )?;
        let mut lat = Vec::with_capacity(n);
        for f in 0..n {
            let one = m.cut(f, f + 1)?;
            let t = Instant::now();
            d.step(one)?;
            lat.push(t.elapsed().as_secs_f64() * 1e3);
        }
        lat.sort_by(f64::total_cmp);
        duet_json = serde_json::json!({
            "performer": file.display().to_string(),
            "prompt_joints": joints,
            "frames": n,
            "answer_ms_p50": percentile(&lat, 0.5),
            "answer_ms_p99": percentile(&lat, 0.99),
            "answer_ms_max": percentile(&lat, 1.0),
        });
    }
    let out = serde_json::json!({
        "duet": duet_json,
        "model": dir.display().to_string(),
        "kind": model.kind(),
        "runtime": engine.runtime().name(),
        "local_step": match &model {
            MotionModel::Frame(s) => serde_json::Value::from(s.local_step_on()),
            _ => serde_json::Value::Null,
        },
        "context_frames": model.context_frames(),
        "load_s": load,
        "window": window,
        "window_forward_ms": window.get("window_forward_ms"),
        "steps": steps,
        "decode_step_ms_p50": decode,
        "stream_frames": frames,
        "frame_ms_p50": q(0.5),
        "frame_ms_p95": q(0.95),
        "frame_ms_p99": q(0.99),
        "frame_ms_max": q(1.0),
        "real_time_factor": frames as f64 / v.fps / total,
        "draws_4": draws4,
        "labelled_default": labelled,
        "allocations_per_frame": allocs,
        "allocations_per_token": allocs / v.frame_len() as f64,
    });
    if json {
        println!("{}", serde_json::to_string(&out)?);
    } else {
        println!("{}", serde_json::to_string_pretty(&out)?);
    }
    Ok(())
}

/// Streams `frames` frames from `g`: per-frame latency p50 / p99 (ms) and
/// the real-time factor at `fps`.
fn stream(
    mut g: choreo::lm::model::MotionGenerator,
    frames: usize,
    free: &[Option<u32>],
    fps: f64,
) -> Result<serde_json::Value> {
    let mut lat = Vec::with_capacity(frames);
    let t = Instant::now();
    for _ in 0..frames {
        let t1 = Instant::now();
        g.next_frame(free)?;
        lat.push(t1.elapsed().as_secs_f64() * 1e3);
    }
    let total = t.elapsed().as_secs_f64();
    lat.sort_by(f64::total_cmp);
    Ok(serde_json::json!({
        "frame_ms_p50": percentile(&lat, 0.5),
        "frame_ms_p99": percentile(&lat, 0.99),
        "real_time_factor": frames as f64 / fps / total,
    }))
}
