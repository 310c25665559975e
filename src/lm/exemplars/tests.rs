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
    let ex = Exemplars::build(&seqs, &v, &kinds, 2.0, 1);
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
    let two = Exemplars::build(&seqs, &v, &kinds, 2.0, 2);
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
