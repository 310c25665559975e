use super::*;

fn vocab() -> Vocabulary {
    let mut labels = BTreeMap::new();
    labels.insert(
        "style".to_string(),
        ["happy", "sad"].iter().map(|s| s.to_string()).collect(),
    );
    labels.insert(
        "content".to_string(),
        ["walk", "run"].iter().map(|s| s.to_string()).collect(),
    );
    Vocabulary::new(labels)
}

fn seq(
    name: &str,
    style: &str,
    content: &str,
    frames: usize,
    v: &Vocabulary,
) -> (String, Labels, Vec<u32>) {
    let mut l = Labels::new();
    l.insert("style".into(), style.into());
    l.insert("content".into(), content.into());
    let fl = v.frame_len();
    // Frame f's tokens are all f (distinct per frame, inside the vocabulary).
    let tokens = (0..frames * fl).map(|i| (i / fl) as u32 % 300).collect();
    (name.into(), l, tokens)
}

#[test]
fn build_pick_and_round_trip() {
    let v = vocab();
    let fl = v.frame_len();
    let seqs = vec![
        seq("a", "happy", "walk", 300, &v),
        seq("b", "happy", "run", 300, &v),
        seq("c", "sad", "walk", 300, &v),
        seq("short", "sad", "run", 10, &v), // under the span: never chosen
    ];
    let kinds = vec!["style".to_string(), "content".to_string()];
    let ex = Exemplars::build(&seqs, &v, &kinds, 2.0, 1, None, SpanChoice::default()).unwrap();
    let len = (2.0 * v.fps).round() as usize;
    assert!(ex
        .items
        .iter()
        .all(|e| e.frames == len && e.source != "short"));
    // Every value with a long enough sequence is covered.
    for (k, val) in [
        ("style", "happy"),
        ("style", "sad"),
        ("content", "walk"),
        ("content", "run"),
    ] {
        assert!(
            ex.items
                .iter()
                .any(|e| e.labels.get(k).map(String::as_str) == Some(val)),
            "{k}={val} uncovered"
        );
    }
    // The span starts a third of the way in, and decodes to the source's tokens.
    for (e, t) in ex.items.iter().zip(&ex.decoded) {
        assert_eq!(e.start_frame, (300 - len) / 3);
        assert_eq!(t.len(), len * fl);
        assert_eq!(t[0], e.start_frame as u32);
        assert_eq!(&e.decode().unwrap(), t);
    }
    // Pick: the best match of all the labels asked for.
    let mut want = Labels::new();
    want.insert("style".into(), "sad".into());
    want.insert("content".into(), "walk".into());
    for seed in 0..20 {
        assert_eq!(ex.pick(&want, seed).unwrap().0.source, "c");
    }
    let mut happy = Labels::new();
    happy.insert("style".into(), "happy".into());
    for s in 0..20 {
        assert_eq!(ex.pick(&happy, s).unwrap().0.labels["style"], "happy");
    }
    // With two per value, both happy sequences are kept and seeds reach both.
    let two = Exemplars::build(&seqs, &v, &kinds, 2.0, 2, None, SpanChoice::default()).unwrap();
    let picked: BTreeSet<&str> = (0..50)
        .map(|s| two.pick(&happy, s).unwrap().0.source.as_str())
        .collect();
    assert_eq!(picked, ["a", "b"].into_iter().collect());
    let mut none = Labels::new();
    none.insert("style".into(), "angry".into());
    assert!(ex.pick(&none, 0).is_none());
    assert!(ex.pick(&Labels::new(), 0).is_none());

    // Save, load, and the same picks.
    let dir = std::env::temp_dir().join(format!("choreo-exemplars-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    ex.save(&dir).unwrap();
    let back = Exemplars::load(&dir, &v).unwrap().unwrap();
    assert_eq!(back.len(), ex.len());
    assert_eq!(back.pick(&want, 3).unwrap().1, ex.pick(&want, 3).unwrap().1);

    // A file that does not fit the model is refused, naming the field.
    let mut wrong = ex.clone();
    wrong.frame_len += 1;
    wrong.save(&dir).unwrap();
    let e = Exemplars::load(&dir, &v).unwrap_err().to_string();
    assert!(e.contains("frame_len"), "{e}");
    let mut wrong = ex.clone();
    wrong.items[0].tokens = Exemplar::encode(&vec![v.size() as u32; len * fl]);
    wrong.save(&dir).unwrap();
    let e = Exemplars::load(&dir, &v).unwrap_err().to_string();
    assert!(
        e.contains("items[0].tokens") && e.contains("outside the vocabulary"),
        "{e}"
    );
    std::fs::write(dir.join(FILE), "{").unwrap();
    let e = Exemplars::load(&dir, &v).unwrap_err().to_string();
    assert!(e.contains("exemplars"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
    // No file: no exemplars, no error.
    assert!(Exemplars::load(&dir, &v).unwrap().is_none());
}

/// A judge of spans by where they start (frame tokens count frames):
/// "happy" and "run" likelier the later, "sad" and "walk" the earlier; no
/// head for anything else.
fn by_start(t: &[u32]) -> Result<crate::lm::model::ClassTable, LmError> {
    let start = t[0] as f64 / 300.0;
    Ok(vec![
        (
            "style".to_string(),
            vec![("happy".into(), start), ("sad".into(), 1.0 - start)],
        ),
        (
            "content".to_string(),
            vec![("walk".into(), 1.0 - start), ("run".into(), start)],
        ),
    ])
}

#[test]
fn a_judge_keeps_the_clearest_spans_and_pick_prefers_them() {
    let v = vocab();
    let fl = v.frame_len();
    let seqs = vec![
        seq("a", "happy", "walk", 300, &v),
        seq("b", "happy", "run", 300, &v),
        seq("c", "happy", "walk", 300, &v),
        seq("d", "sad", "walk", 300, &v),
    ];
    let kinds = vec!["style".to_string(), "content".to_string()];
    // The judge: "happy" is likelier the later the span starts, and "walk"
    // the earlier.
    let judge = by_start;
    let ex = Exemplars::build(
        &seqs,
        &v,
        &kinds,
        2.0,
        2,
        Some(&judge),
        SpanChoice::default(),
    )
    .unwrap();
    let len = (2.0 * v.fps).round() as usize;
    let starts: Vec<usize> = (1..=CANDIDATES)
        .map(|c| (300 - len) * c / (CANDIDATES + 1))
        .collect();
    let (first, last) = (starts[0], *starts.last().unwrap());
    let chosen = |k: &str, val: &str| -> Vec<(&str, usize, f64)> {
        ex.items
            .iter()
            .filter_map(|e| {
                e.chosen_for
                    .iter()
                    .find(|c| c.kind == k && c.value == val)
                    .map(|c| (e.source.as_str(), e.start_frame, c.p.unwrap()))
            })
            .collect()
    };
    // Two happy spans, from two different sequences, both the latest span
    // of their sequence; walk's from the earliest.
    let happy = chosen("style", "happy");
    assert_eq!(happy.len(), 2);
    assert_ne!(happy[0].0, happy[1].0);
    assert!(happy.iter().all(|h| h.1 == last), "{happy:?}");
    let walk = chosen("content", "walk");
    assert_eq!(walk.len(), 2);
    assert!(walk.iter().all(|w| w.1 == first), "{walk:?}");
    // Sad has one sequence, and sad is likelier early.
    assert_eq!(
        chosen("style", "sad"),
        vec![("d", first, 1.0 - first as f64 / 300.0)]
    );
    // Every stored span decodes to its source's frames.
    for (e, t) in ex.items.iter().zip(&ex.decoded) {
        assert_eq!(t.len(), len * fl);
        assert_eq!(t[0], e.start_frame as u32);
    }
    // Pick for happy: only the spans chosen for happy, though walk spans of
    // happy sequences carry the label too.
    let mut want = Labels::new();
    want.insert("style".into(), "happy".into());
    for s in 0..40 {
        let (e, _) = ex.pick(&want, s).unwrap();
        assert!(
            e.chosen_for.iter().any(|c| c.value == "happy"),
            "{:?}",
            e.chosen_for
        );
    }
    // The file round-trips with the choices.
    let dir = std::env::temp_dir().join(format!("choreo-exemplars-j-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    ex.save(&dir).unwrap();
    let back = Exemplars::load(&dir, &v).unwrap().unwrap();
    assert_eq!(back.items[0].chosen_for, ex.items[0].chosen_for);
    std::fs::remove_dir_all(&dir).unwrap();
    // A judge that fails fails the build.
    let bad = |_: &[u32]| -> Result<crate::lm::model::ClassTable, LmError> {
        Err(LmError::invalid("model", "classes", "no heads"))
    };
    assert!(
        Exemplars::build(&seqs, &v, &kinds, 2.0, 1, Some(&bad), SpanChoice::default()).is_err()
    );
}

#[test]
fn covering_a_kind_spreads_a_values_spans_over_it() {
    let v = vocab();
    let fl = v.frame_len();
    // Three happy takes; a judge that likes the walks best (frame tokens
    // start at each take's offset, and happiness grows with the token).
    let take = |name: &str, content: &str, offset: u32| {
        let mut s = seq(name, "happy", content, 300, &v);
        s.2 = (0..300 * fl)
            .map(|i| (i / fl) as u32 / 2 + offset)
            .collect();
        s
    };
    let seqs = vec![
        take("walk-a", "walk", 120),
        take("walk-b", "walk", 110),
        take("run", "run", 0),
    ];
    let judge = |t: &[u32]| -> Result<crate::lm::model::ClassTable, LmError> {
        let p = t[0] as f64 / 400.0;
        Ok(vec![(
            "style".to_string(),
            vec![("happy".into(), p), ("sad".into(), 1.0 - p)],
        )])
    };
    let kinds = vec!["style".to_string()];
    let sources = |ex: &Exemplars| -> BTreeSet<String> {
        ex.items.iter().map(|e| e.source.clone()).collect()
    };
    let build = |per_label: usize, cover: Option<&str>| {
        let choice = SpanChoice {
            cover,
            from_start: false,
        };
        Exemplars::build(&seqs, &v, &kinds, 2.0, per_label, Some(&judge), choice).unwrap()
    };
    let plain = build(2, None);
    assert_eq!(
        sources(&plain),
        ["walk-a", "walk-b"].map(String::from).into()
    );
    let covered = build(2, Some("content"));
    // The best walk, then the best run: the run take gets its turn.
    assert_eq!(
        sources(&covered),
        ["walk-a", "run"].map(String::from).into()
    );
    // Three per value: every take, each once.
    let all = build(3, Some("content"));
    assert_eq!(all.len(), 3);
    // Turn-taking keeps each group's order.
    assert_eq!(
        spread_over(
            vec![(1, 'a'), (2, 'a'), (3, 'b'), (4, 'a'), (5, 'c')],
            |x| x.1
        ),
        vec![(1, 'a'), (3, 'b'), (5, 'c'), (2, 'a'), (4, 'a')]
    );
}

#[test]
fn a_value_with_only_short_takes_gets_them_whole() {
    let v = vocab();
    let fl = v.frame_len();
    let len = (2.0 * v.fps).round() as usize; // 40 frames
    let seqs = vec![
        seq("long-walk", "happy", "walk", 300, &v),
        seq("run-25", "sad", "run", 25, &v),
        seq("run-30", "sad", "run", 30, &v),
        seq("too-short", "sad", "run", 5, &v), // under 0.3 of a span
    ];
    let kinds = vec!["style".to_string(), "content".to_string()];
    let ex = Exemplars::build(&seqs, &v, &kinds, 2.0, 2, None, SpanChoice::default()).unwrap();
    let mut sad = Labels::new();
    sad.insert("style".into(), "sad".into());
    let picked: BTreeSet<(String, usize)> = (0..40)
        .map(|s| {
            let (e, t) = ex.pick(&sad, s).unwrap();
            assert_eq!(t.len(), e.frames * fl);
            assert_eq!((e.start_frame, t[0]), (0, 0));
            (e.source.clone(), e.frames)
        })
        .collect();
    assert_eq!(
        picked,
        [("run-25".to_string(), 25), ("run-30".to_string(), 30)].into()
    );
    // The long take keeps its span of the asked length, and the short
    // ones are stored once though chosen for style and content both.
    assert!(ex
        .items
        .iter()
        .any(|e| e.source == "long-walk" && e.frames == len));
    assert_eq!(ex.items.iter().filter(|e| e.source == "run-30").count(), 1);
    let run30 = ex.items.iter().find(|e| e.source == "run-30").unwrap();
    assert_eq!(run30.chosen_for.len(), 2);
    assert!(ex.items.iter().all(|e| e.source != "too-short"));
    // Saved and loaded with their own lengths.
    let dir = std::env::temp_dir().join(format!("choreo-exemplars-s-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    ex.save(&dir).unwrap();
    let back = Exemplars::load(&dir, &v).unwrap().unwrap();
    assert_eq!(back.pick(&sad, 3).unwrap().1, ex.pick(&sad, 3).unwrap().1);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn from_start_takes_each_span_from_its_takes_opening() {
    let v = vocab();
    let fl = v.frame_len();
    let seqs = vec![
        seq("a", "happy", "walk", 300, &v),
        seq("b", "happy", "walk", 280, &v),
        seq("c", "happy", "run", 60, &v),
        seq("d", "sad", "walk", 300, &v),
    ];
    let kinds = vec!["style".to_string(), "content".to_string()];
    // Happiness grows with a span's start: from inside the takes the
    // judge would pick their last candidate spans; openings have no choice.
    let judge = by_start;
    let choice = SpanChoice {
        cover: Some("content"),
        from_start: true,
    };
    let build = |choice| Exemplars::build(&seqs, &v, &kinds, 2.0, 2, Some(&judge), choice).unwrap();
    let ex = build(choice);
    let len = (2.0 * v.fps).round() as usize;
    assert!(!ex.is_empty());
    for (e, d) in ex.items.iter().zip(&ex.decoded) {
        let s = seqs.iter().find(|s| s.0 == e.source).unwrap();
        assert_eq!((e.start_frame, e.frames), (0, len), "{e:?}");
        assert_eq!(d[..], s.2[..len * fl]);
    }
    // Happy's two spans cover both its contents: the best walk opening and
    // the run's (a take only 3 s long, whose opening is still a span).
    let happy: BTreeSet<&str> = ex
        .items
        .iter()
        .filter(|e| e.chosen_for.iter().any(|c| c.value == "happy"))
        .map(|e| e.labels["content"].as_str())
        .collect();
    assert_eq!(happy, ["run", "walk"].into_iter().collect());
    // Without from_start the same judge takes spans from inside the takes.
    let inside = build(SpanChoice {
        from_start: false,
        ..choice
    });
    assert!(inside.items.iter().all(|e| e.start_frame > 0));
}

#[test]
fn rewriting_one_kind_keeps_the_other_kinds_spans() {
    let v = vocab();
    let seqs = vec![
        seq("a", "happy", "walk", 300, &v),
        seq("b", "sad", "run", 300, &v),
    ];
    let both = vec!["style".to_string(), "content".to_string()];
    let style = vec!["style".to_string()];
    let old = Exemplars::build(&seqs, &v, &both, 2.0, 1, None, SpanChoice::default()).unwrap();
    let chosen = |ex: &Exemplars, kind: &str| -> usize {
        ex.items
            .iter()
            .map(|e| e.chosen_for.iter().filter(|c| c.kind == kind).count())
            .sum()
    };
    assert_eq!((chosen(&old, "style"), chosen(&old, "content")), (2, 2));
    // Style rewritten with 1 s spans: the content choices survive, the old
    // style choices do not, and the new spans keep their own length.
    let mut new = Exemplars::build(&seqs, &v, &style, 1.0, 1, None, SpanChoice::default()).unwrap();
    let n_new = new.len();
    let kept = new.keep_others(old.clone(), &style);
    assert!(kept >= 1 && new.len() == n_new + kept);
    assert_eq!((chosen(&new, "style"), chosen(&new, "content")), (2, 2));
    let short = (1.0 * v.fps).round() as usize;
    assert!(new.items[..n_new].iter().all(|e| e.frames == short));
    assert!(new.items[n_new..]
        .iter()
        .all(|e| e.frames == 2 * short && e.chosen_for.iter().all(|c| c.kind == "content")));
    // A content request still gets a content span, a style request a new
    // style span; the merged file loads back whole.
    let mut walk = Labels::new();
    walk.insert("content".into(), "walk".into());
    let (e, t) = new.pick(&walk, 3).unwrap();
    assert!(
        e.chosen_for.iter().any(|c| c.kind == "content") && t.len() == e.frames * v.frame_len()
    );
    let mut happy = Labels::new();
    happy.insert("style".into(), "happy".into());
    assert_eq!(new.pick(&happy, 3).unwrap().0.frames, short);
    let dir = tempfile::tempdir().unwrap();
    new.save(dir.path()).unwrap();
    let back = Exemplars::load(dir.path(), &v).unwrap().unwrap();
    assert_eq!(back.len(), new.len());
    // A file from before `chosen_for`: its spans carrying a style go.
    let mut legacy = old;
    legacy.items.iter_mut().for_each(|e| e.chosen_for.clear());
    let mut again =
        Exemplars::build(&seqs, &v, &style, 1.0, 1, None, SpanChoice::default()).unwrap();
    assert_eq!(again.keep_others(legacy, &style), 0);
}

#[test]
fn the_same_spans_come_back_encoded_afresh() {
    let v = vocab();
    // Read from folders: the span keeps the file name only. Two corpora
    // hold a file "b.bvh"; the labels tell them apart.
    let seqs = vec![
        seq("x/a.bvh", "happy", "walk", 300, &v),
        seq("x/b.bvh", "sad", "run", 300, &v),
        seq("y/b.bvh", "happy", "run", 300, &v),
    ];
    let both = vec!["style".to_string(), "content".to_string()];
    let old = Exemplars::build(&seqs, &v, &both, 2.0, 1, None, SpanChoice::default()).unwrap();
    assert!(old.items.iter().all(|e| !e.source.contains('/')));
    let dir = tempfile::tempdir().unwrap();
    old.save(dir.path()).unwrap();
    // "Another layout": every token one higher.
    let shifted: Vec<_> = seqs
        .iter()
        .map(|(n, l, t)| {
            (
                n.clone(),
                l.clone(),
                t.iter().map(|x| x + 1).collect::<Vec<u32>>(),
            )
        })
        .collect();
    let file = dir.path().join(FILE);
    let new = Exemplars::reencoded(&file, &shifted, &v).unwrap();
    assert_eq!(new.len(), old.len());
    for (a, b) in old.items.iter().zip(&new.items) {
        assert_eq!(
            (&a.source, a.start_frame, a.frames, &a.labels),
            (&b.source, b.start_frame, b.frames, &b.labels)
        );
        let (ta, tb) = (a.decode().unwrap(), b.decode().unwrap());
        assert!(ta.iter().zip(&tb).all(|(x, y)| y == &(x + 1)));
    }
    // A source the folders no longer hold is an error naming the item.
    let e = Exemplars::reencoded(&file, &shifted[..1], &v)
        .unwrap_err()
        .to_string();
    assert!(e.contains("source") && e.contains("not among"), "{e}");
}
