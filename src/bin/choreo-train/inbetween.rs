//! The learned in-betweener: training, export, held-out evaluation.

use super::*;

pub(crate) fn inbetween(a: InbetweenArgs) -> Result<()> {
    use choreo::lm::inbetween::{InbetweenConfig, Inbetweener};
    use choreo::train::inbetween as ib;
    use rand::SeedableRng;
    let cfg = InbetweenConfig {
        window: a.window,
        d_model: a.d_model,
        n_layers: a.layers,
        n_heads: a.heads,
        d_ff: 4 * a.d_model,
        ln_eps: 1e-5,
        condition: None,
        base: a.base.unwrap_or_default(),
    };
    let dirs = choreo::train::data::corpus_dirs(&a.data.data, &a.data.corpora)?;
    let (motions, info) = choreo::train::data::read_motions(&dirs)?;
    let condition = match &a.condition {
        None => None,
        Some(kind) => {
            let values: std::collections::BTreeSet<String> = motions
                .iter()
                .filter_map(|(_, m)| m.labels.get(kind).cloned())
                .collect();
            if values.is_empty() {
                anyhow::bail!("--condition {kind}: no motion carries that label");
            }
            Some((kind.clone(), values.into_iter().collect::<Vec<_>>()))
        }
    };
    let init = a.init.as_deref().map(Inbetweener::load).transpose()?;
    let cfg = match &init {
        // The parent's architecture and conditioning; its base unless this
        // run names one (a SLERP model can be fine-tuned onto Catmull-Rom).
        Some(m) => InbetweenConfig {
            base: a.base.unwrap_or(m.manifest.config.base),
            ..m.manifest.config.clone()
        },
        None => InbetweenConfig { condition, ..cfg },
    };
    cfg.validate("--window/--d-model/--heads")?;
    let (train, val) = ib::prepare(motions, a.data.val_fraction, cfg.window + 1, a.mirror)?;
    let corpus_share = match &a.corpus_share {
        None => None,
        Some(v) => {
            let (c, f) = v
                .split_once('=')
                .with_context(|| format!("--corpus-share: '{v}' is not CORPUS=FRACTION"))?;
            let f: f64 = f
                .parse()
                .ok()
                .filter(|f| (0.0..=1.0).contains(f))
                .with_context(|| format!("--corpus-share: '{f}' is not a fraction in 0..=1"))?;
            Some((c.to_string(), f))
        }
    };
    eprintln!(
        "{} training clips, {} held out ({} corpora)",
        train.len(),
        val.len(),
        info.corpora.len()
    );
    let dev = choreo::train::device();
    let net = ib::InbetweenNet::new(cfg.clone(), &dev)?;
    if let Some(m) = &init {
        net.load_from_export(m, &dev)?;
        eprintln!("fine-tuning from {}", m.onnx_path.display());
    }
    eprintln!("{} parameters", net.params.count());
    let settings = ib::Settings {
        steps: a.steps,
        batch: a.batch,
        lr: a.lr,
        warmup: (a.steps / 20).max(1),
        weight_decay: 0.01,
        spacing: (a.spacing[0].max(2), a.spacing[1].max(a.spacing[0].max(2))),
        seed: a.seed,
        max_seconds: (a.max_seconds > 0.0).then_some(a.max_seconds),
        corpus_share,
        loss_weights: a.loss_weights,
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(a.seed);
    let t0 = std::time::Instant::now();
    let mut curve = Vec::new();
    let mut ema = f64::NAN;
    let steps = ib::train(
        &net,
        &train,
        &settings,
        &mut rng,
        &dev,
        &mut |step, loss, lr| {
            ema = if ema.is_nan() {
                loss
            } else {
                0.95 * ema + 0.05 * loss
            };
            curve.push((step, loss));
            if step % 50 == 0 || step + 1 == settings.steps {
                eprintln!(
                    "step {step:>5}  loss {loss:.5}  (ema {ema:.5})  lr {lr:.2e}  {:.0} s",
                    t0.elapsed().as_secs_f64()
                );
            }
        },
    )?;
    let secs = t0.elapsed().as_secs_f64();
    // Export, load back in tract, check parity, evaluate the export.
    let mut training = serde_json::json!({"settings": settings, "steps_done": steps, "seconds": secs,
        "base": cfg.base,
        "train_clips": train.len(), "val_clips": val.len(),
        "final_loss_ema": ema});
    let mut info = info;
    if let Some(m) = &init {
        // Lineage: the parent's own training record (with its parents), the
        // time of the whole line, and every licence that touched the weights.
        let parent = &m.manifest.training;
        let before = parent["total_seconds"]
            .as_f64()
            .or_else(|| parent["seconds"].as_f64())
            .unwrap_or(0.0);
        training["parent"] = parent.clone();
        training["total_seconds"] = serde_json::json!(before + secs);
        for l in &m.manifest.data.licences {
            if !info.licences.contains(l) {
                info.licences.push(l.clone());
            }
        }
    }
    let mut manifest = ib::export(&net, info, Default::default(), training, &a.out)?;
    let model = Inbetweener::load(&a.out)?;
    let parity = ib::parity(&net, &model, &mut rng)?;
    let rows = ib::evaluate(&model, &train, &val, &a.eval_spacing)?;
    let metrics = &mut manifest.metrics;
    metrics.insert("parity_max_abs".to_string(), parity);
    for r in &rows {
        metrics.insert(format!("val_slerp_cm2_s{}", r.spacing), r.slerp_cm2);
        metrics.insert(
            format!("val_bezier_avg_cm2_s{}", r.spacing),
            r.bezier_avg_cm2,
        );
        metrics.insert(
            format!("val_catmull_rom_cm2_s{}", r.spacing),
            r.catmull_rom_cm2,
        );
        metrics.insert(format!("val_learned_cm2_s{}", r.spacing), r.learned_cm2);
    }
    ib::write_manifest(&manifest, &a.out)?;
    let report = serde_json::json!({"parity_max_abs": parity, "steps": steps, "seconds": secs,
        "val_clips": val.iter().map(|c| format!("{}/{}", c.corpus, c.name)).collect::<Vec<_>>(),
        "rows": rows});
    std::fs::write(
        a.out.join("eval.json"),
        serde_json::to_string_pretty(&report)? + "\n",
    )?;
    println!("trained {steps} steps in {secs:.0} s; tract vs candle max |Δ| {parity:.2e}");
    print_inbetween_rows("all held-out clips", &rows);
    Ok(())
}

pub(crate) fn print_inbetween_rows(title: &str, rows: &[choreo::train::inbetween::EvalRow]) {
    println!("{title}: held-out MSE on FK positions, cm² (mean over clips)");
    println!(
        "spacing  clips    slerp  bezier-avg  catmull-rom  learned  (bezier fitted to the clip)"
    );
    for r in rows {
        println!(
            "{:>7}  {:>5}  {:>7.3}  {:>10.3}  {:>11.3}  {:>7.3}  ({:.3})",
            r.spacing,
            r.clips,
            r.slerp_cm2,
            r.bezier_avg_cm2,
            r.catmull_rom_cm2,
            r.learned_cm2,
            r.bezier_fit_cm2
        );
    }
}

pub(crate) fn eval_inbetween(
    model: &Path,
    d: &DataArgs,
    spacings: &[usize],
    json: bool,
) -> Result<()> {
    use choreo::train::inbetween as ib;
    let model = choreo::lm::inbetween::Inbetweener::load(model)?;
    let dirs = choreo::train::data::corpus_dirs(&d.data, &d.corpora)?;
    let (motions, _) = choreo::train::data::read_motions(&dirs)?;
    let (train, val) = ib::prepare(motions, d.val_fraction, model.config().window + 1, false)?;
    let mut out = Vec::new();
    let mut corpora: Vec<String> = val.iter().map(|c| c.corpus.clone()).collect();
    corpora.dedup();
    for c in corpora {
        let sub: Vec<ib::Clip> = val
            .iter()
            .filter(|x| x.corpus == c)
            .map(|x| ib::Clip {
                corpus: x.corpus.clone(),
                name: x.name.clone(),
                labels: x.labels.clone(),
                motion: x.motion.clone(),
            })
            .collect();
        let rows = ib::evaluate(&model, &train, &sub, spacings)?;
        let names: Vec<String> = sub.iter().map(|x| x.name.clone()).collect();
        if !json {
            print_inbetween_rows(&format!("{c} ({} clips)", sub.len()), &rows);
        }
        out.push(serde_json::json!({"corpus": c, "clips": names, "rows": rows}));
    }
    let rows = ib::evaluate(&model, &train, &val, spacings)?;
    if json {
        out.push(serde_json::json!({"corpus": "all", "rows": rows}));
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_inbetween_rows("all", &rows);
    }
    Ok(())
}
