//! `choreo eval generate`: prints the generation table (see
//! `choreo::eval::generate`).

use anyhow::{bail, Context, Result};
use choreo::eval::generate::{eval_generate, GenOptions, GenRow};
use choreo::lm::model::MotionModel;
use choreo::lm::Sampling;
use std::path::{Path, PathBuf};

/// `T:K:P[:G[:N[:J[:W[:C[:D[:A[:R[:E[:M[:V[:S]]]]]]]]]]]]` (temperature,
/// top-k, top-p, guidance, keep_near, max_jump, posture, context, draws,
/// pace, jerk, ease, matching, travel, skate), or `greedy`.
pub fn parse_sampling(s: &str) -> Result<Sampling> {
    if s == "greedy" {
        return Ok(Sampling::default());
    }
    let parts: Vec<&str> = s.split(':').collect();
    if !(3..=15).contains(&parts.len()) {
        bail!(
            "--sampling: '{s}' is not T:K:P[:G[:N[:J[:W[:C[:D[:A[:R[:E[:M[:V[:S]]]]]]]]]]]] (temperature:top_k:top_p[:guidance[:keep_near[:max_jump[:posture[:context[:draws[:pace[:jerk[:ease[:matching[:travel[:skate]]]]]]]]]]]]) or greedy"
        );
    }
    // The optional fields, each its "off" value when left out.
    let field = |i: usize, off: &'static str| parts.get(i).copied().unwrap_or(off);
    let (t, k, p) = (parts[0], parts[1], parts[2]);
    let (e, m, v, sk) = (
        field(11, "0"),
        field(12, "0"),
        field(13, "1"),
        field(14, "0"),
    );
    let (g, n, j, w, c, d, a, r) = (
        field(3, "1"),
        field(4, "0"),
        field(5, "0"),
        field(6, "0"),
        field(7, "0"),
        field(8, "1"),
        field(9, "0"),
        field(10, "0"),
    );
    let sm = Sampling {
        temperature: t
            .parse()
            .with_context(|| format!("--sampling: temperature '{t}'"))?,
        top_k: k
            .parse()
            .with_context(|| format!("--sampling: top_k '{k}'"))?,
        top_p: p
            .parse()
            .with_context(|| format!("--sampling: top_p '{p}'"))?,
        seed: 0,
        guidance: g
            .parse()
            .with_context(|| format!("--sampling: guidance '{g}'"))?,
        keep_near: n
            .parse()
            .with_context(|| format!("--sampling: keep_near '{n}'"))?,
        max_jump: j
            .parse()
            .with_context(|| format!("--sampling: max_jump '{j}'"))?,
        posture: w
            .parse()
            .with_context(|| format!("--sampling: posture '{w}'"))?,
        context: c
            .parse()
            .with_context(|| format!("--sampling: context '{c}'"))?,
        draws: d
            .parse()
            .with_context(|| format!("--sampling: draws '{d}'"))?,
        pace: a
            .parse()
            .with_context(|| format!("--sampling: pace '{a}'"))?,
        jerk: r
            .parse()
            .with_context(|| format!("--sampling: jerk '{r}'"))?,
        ease: e
            .parse()
            .with_context(|| format!("--sampling: ease '{e}'"))?,
        matching: m
            .parse()
            .with_context(|| format!("--sampling: matching '{m}'"))?,
        travel: v
            .parse()
            .with_context(|| format!("--sampling: travel '{v}'"))?,
        skate: sk
            .parse()
            .with_context(|| format!("--sampling: skate '{sk}'"))?,
    };
    sm.validate()
        .map_err(|e| anyhow::anyhow!("--sampling: {e}"))?;
    Ok(sm)
}

pub fn run(
    model: &Path,
    data: &Path,
    labels: &str,
    (per_label, seconds, lengths): (usize, f64, &str),
    (samplings, seed): (&[String], u64),
    (exemplar, candidates, rank_every): (&str, &[u32], usize),
    (root, feet): (&str, &str),
    json: bool,
) -> Result<()> {
    if per_label == 0 {
        bail!("--per-label must be at least 1");
    }
    if !(seconds > 0.0 && seconds <= 120.0) {
        bail!("--seconds: {seconds} (want 0 < s ≤ 120)");
    }
    let held_out_lengths = match lengths {
        "fixed" => false,
        "held-out" => true,
        o => bail!("--lengths: '{o}' is not fixed or held-out"),
    };
    let root_from_feet = match root {
        "model" => vec![false],
        "feet" => vec![true],
        "both" => vec![false, true],
        o => bail!("--root: '{o}' is not model, feet or both"),
    };
    let pin_feet = match feet {
        "model" => vec![false],
        "pin" => vec![true],
        "both" => vec![false, true],
        o => bail!("--feet: '{o}' is not model, pin or both"),
    };
    let m = MotionModel::load(model).with_context(|| format!("--model {}", model.display()))?;
    let kind = [labels.to_string()];
    let samplings = samplings
        .iter()
        .map(|s| {
            if s == "default" {
                // What a request for this label kind naming no sampling gets.
                let mut sm = choreo::lm::sampling::RECOMMENDED;
                m.fill_kind_defaults(&kind, &mut sm, Default::default());
                return Ok(Sampling { seed, ..sm });
            }
            // J `auto`: the model's default for the label kind.
            let j = m.default_max_jump(&kind).to_string();
            let s = s
                .split(':')
                .enumerate()
                .map(|(i, p)| if i == 5 && p == "auto" { &j[..] } else { p })
                .collect::<Vec<_>>()
                .join(":");
            parse_sampling(&s).map(|sm| Sampling { seed, ..sm })
        })
        .collect::<Result<Vec<_>>>()?;
    let exemplar_modes = match exemplar {
        "none" => vec![false],
        "auto" => vec![true],
        "both" => vec![false, true],
        o => bail!("--exemplar: '{o}' is not none, auto or both"),
    };
    let exemplars = choreo::lm::exemplars::Exemplars::load(model, m.vocabulary())
        .with_context(|| format!("--model {}", model.display()))?;
    let o = GenOptions {
        label_kind: labels.to_string(),
        per_label,
        seconds,
        held_out_lengths,
        samplings,
        val_fraction: 0.1,
        exemplar_modes: match (&exemplars, exemplar) {
            // Without exemplars, `both` measures the one mode there is.
            (None, "both") => vec![false],
            _ => exemplar_modes,
        },
        exemplars,
        candidates: candidates.to_vec(),
        rank_every,
        root_from_feet,
        pin_feet,
    };
    let rows = eval_generate(&m, data, &o, &mut |line| eprintln!("{line}"))?;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({ "model": m.kind(), "rows": rows }))?
        );
        return Ok(());
    }
    let f = |x: Option<f64>| x.map_or("-".into(), |v| format!("{v:.1}"));
    let range = |x: Option<[f64; 2]>| x.map_or(String::new(), |[a, b]| format!(" [{a:.1}–{b:.1}]"));
    println!(
        "{} model, {} clips of {} per {labels}, held-out clips of {}",
        m.kind(),
        per_label,
        match rows.first() {
            Some(r) if held_out_lengths => format!(
                "the held-out segments' lengths (mean {:.1} s, at most {seconds} s)",
                r.seconds_generated
            ),
            _ => format!("{seconds} s"),
        },
        PathBuf::from(data).display()
    );
    println!(
        "| sampling | FID_k [5–95 % over resampled clips] (real; real at this clip count) | FID_g [5–95 %] (real; same count) | accel × | jerk × | skate × | frozen (real) | diversity (real) | cond acc (real) | s/clip |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {}{} ({}; {}) | {}{} ({}; {}) | {:.2} | {:.2} | {:.2} | {:.0} % ({:.0} %) | {:.2} ({:.2}) | {:.0} % ({:.0} %) | {:.2} |",
            r.sampling,
            f(r.fid_k),
            range(r.fid_k_range),
            f(r.fid_k_real),
            f(r.fid_k_real_same_n),
            f(r.fid_g),
            range(r.fid_g_range),
            f(r.fid_g_real),
            f(r.fid_g_real_same_n),
            r.accel_ratio,
            r.jerk_ratio,
            r.skate_ratio,
            100.0 * r.frozen,
            100.0 * r.frozen_real,
            r.diversity,
            r.diversity_real,
            100.0 * r.cond_acc,
            100.0 * r.cond_acc_real,
            r.seconds_per_clip
        );
    }
    if rows.iter().any(|r| r.root_in_place) {
        println!("(root held in place on both sides: the real clips have no root trajectory)");
    }
    // One line per row under a heading: each row's sampling, then what
    // `line` makes of it.
    let per_row = |heading: String, line: &dyn Fn(&GenRow) -> String| {
        println!("{heading}");
        for r in &rows {
            println!("  {}: {}", r.sampling, line(r));
        }
    };
    per_row(
        "kinetic features furthest from held-out real (mean shift in real SDs, spread ×):".into(),
        &|r| {
            let g: Vec<String> = r
                .fid_k_gaps
                .iter()
                .map(|g| format!("{} {:+.1} ×{:.2}", g.feature, g.z, g.spread))
                .collect();
            g.join(", ")
        },
    );
    per_row(
        "FID_k along the real clips' first principal axis (their activity) and without it:".into(),
        &|r| match &r.fid_k_axis {
            Some(a) => format!(
                "axis {:.0} % of real variance, spread {:.2}× real, shift {:+.2} SD, cost {:.1}; \
                 without it {:.1} (real {})",
                100.0 * a.real_share,
                (a.gen_var / a.real_var.max(1e-24)).sqrt(),
                a.shift,
                a.cost,
                a.fid_k_without,
                f(a.fid_k_real_same_n_without)
            ),
            None => "-".into(),
        },
    );
    per_row(
        "cond acc per label value, generated (held-out real):".into(),
        &|r| {
            let g: Vec<String> = r
                .cond_acc_by_label
                .iter()
                .map(|(v, a)| {
                    let real = a.real.map_or("-".into(), |x| format!("{:.0}", 100.0 * x));
                    format!("{v} {:.0} ({real})", 100.0 * a.generated)
                })
                .collect();
            format!("{} %", g.join(", "))
        },
    );
    per_row(
        "cond acc by 2 s window of the clip (does the label hold?):".into(),
        &|r| {
            let w: Vec<String> = r
                .cond_acc_windows
                .iter()
                .map(|a| format!("{:.0}", 100.0 * a))
                .collect();
            format!("{} %", w.join(" / "))
        },
    );
    per_row(
        format!(
            "frames tilted past 99 % of real training frames ({:.0}°) / lowest joint off their 0.5–99.5 % band widened 2.5 cm ({:.3}–{:.3} m) (held-out real):",
            rows.first().map_or(f64::NAN, |r| r.tilt_max),
            rows.first().map_or(f64::NAN, |r| r.floor_band[0]),
            rows.first().map_or(f64::NAN, |r| r.floor_band[1])
        ),
        &|r| {
            format!(
                "{:.1} % ({:.1} %) / {:.1} % ({:.1} %)",
                100.0 * r.tilt_out,
                100.0 * r.tilt_out_real,
                100.0 * r.floor_out,
                100.0 * r.floor_out_real
            )
        },
    );
    Ok(())
}
