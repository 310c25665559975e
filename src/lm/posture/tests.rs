use super::*;

#[test]
fn tilt_is_the_up_axis_angle_from_the_vertical_whatever_the_heading() {
    use crate::motion::rotation::{axis_angle_to_quat, quat_mul, quat_rotate, quat_to_axis_angle};
    // A turn about the vertical alone: upright, at any heading.
    for h in [0.0, 1.0, 3.0, -2.5] {
        assert!(up_tilt_degrees([0.0, h, 0.0]).abs() < 1e-6);
    }
    // A 30° bow (about x) under headings round the circle, π included
    // (where the axis-angle components are farthest from the tilt).
    for h in [0.0, 1.0, std::f64::consts::PI, -2.0] {
        let q = quat_mul(
            axis_angle_to_quat([0.0, h, 0.0]),
            axis_angle_to_quat([30f64.to_radians(), 0.0, 0.0]),
        );
        let t = up_tilt_degrees(quat_to_axis_angle(q));
        assert!((t - 30.0).abs() < 1e-6, "heading {h}: {t}");
    }
    // Any rotation: the angle the rotated up axis makes with +y.
    for aa in [[0.3, -1.2, 0.8], [-1.5, 0.1, 0.15], [2.0, 2.0, -1.0]] {
        let up = quat_rotate(axis_angle_to_quat(aa), [0.0, 1.0, 0.0]);
        let want = up[1].clamp(-1.0, 1.0).acos().to_degrees();
        assert!((up_tilt_degrees(aa) - want).abs() < 1e-6, "{aa:?}");
    }
}

/// Postures over `slots` slots and 360 bins with one clustered label
/// (style `happy`: two pose clusters, slot 3 at bins 10 or 100) and one
/// unclustered (content `wave`: slot 4 at bin 200).
fn two_cluster_postures(slots: usize) -> Postures {
    let mut frames: Vec<Vec<u32>> = Vec::new();
    for i in 0..300u32 {
        let mut f = vec![0u32; slots];
        // 200 frames near bin 10, 100 near bin 100 (±2 bins).
        f[3] = if i < 200 { 8 + i % 5 } else { 98 + i % 5 };
        frames.push(f);
    }
    let refs: Vec<&[u32]> = frames.iter().map(|f| &f[..]).collect();
    let comps = cluster(&refs, 2, 360.0, slots);
    let stat = |mean: f64| SlotStat { mean, spread: 5.0 };
    let mut happy = vec![None; slots];
    happy[3] = Some(stat(40.0));
    let mut wave = vec![None; slots];
    wave[4] = Some(stat(200.0));
    let labels = BTreeMap::from([
        (
            "style".to_string(),
            BTreeMap::from([("happy".to_string(), happy)]),
        ),
        (
            "content".to_string(),
            BTreeMap::from([("wave".to_string(), wave)]),
        ),
    ]);
    Postures {
        bins: 360,
        slots,
        frames: BTreeMap::new(),
        labels,
        tilt: BTreeMap::new(),
        components: BTreeMap::from([(
            "style".to_string(),
            BTreeMap::from([("happy".to_string(), comps)]),
        )]),
    }
}

fn peak(row: &[f32]) -> usize {
    (0..row.len())
        .max_by(|&a, &b| row[a].total_cmp(&row[b]))
        .unwrap()
}

#[test]
fn pose_clusters_split_a_label_and_the_pull_follows_the_previous_frame() {
    let slots = 8;
    let p = two_cluster_postures(slots);
    let cs = &p.components["style"]["happy"];
    assert_eq!(cs.len(), 2);
    let mut found: Vec<(f64, f64)> = cs
        .iter()
        .map(|c| (c.slots[3].as_ref().unwrap().mean, c.weight))
        .collect();
    found.sort_by(|a, b| a.0.total_cmp(&b.0));
    assert!(
        (found[0].0 - 10.0).abs() < 0.5 && (found[0].1 - 2.0 / 3.0).abs() < 1e-9,
        "{found:?}"
    );
    assert!(
        (found[1].0 - 100.0).abs() < 0.5 && (found[1].1 - 1.0 / 3.0).abs() < 1e-9,
        "{found:?}"
    );
    // Root and root-velocity slots are not pulled, so not clustered.
    assert!(cs
        .iter()
        .all(|c| c.slots[0].is_none() && c.slots[slots - 2].is_none()));

    let labels: Labels = [("style".to_string(), "happy".to_string())]
        .into_iter()
        .collect();
    let pull = p.pull(&labels, 1.0).unwrap();
    let mut prev = vec![0u32; slots];
    // Without a previous frame: the label's one mean pose (bin 40).
    assert_eq!(peak(&pull.for_frame(None, 1.0).slot(3, &[], None)), 40);
    // A previous frame in either cluster: that cluster's pose.
    prev[3] = 12;
    assert_eq!(
        peak(&pull.for_frame(Some(&prev), 1.0).slot(3, &[], None)),
        10
    );
    prev[3] = 97;
    assert_eq!(
        peak(&pull.for_frame(Some(&prev), 1.0).slot(3, &[], None)),
        100
    );
    // Halfway, both clusters pull: the peak lies between them.
    prev[3] = 55;
    let mid = peak(&pull.for_frame(Some(&prev), 1.0).slot(3, &[], None));
    assert!((10..=100).contains(&mid), "{mid}");
    // The weight scales the offsets.
    let pull2 = p.pull(&labels, 2.0).unwrap();
    prev[3] = 12;
    let (a, b) = (
        pull.for_frame(Some(&prev), 1.0).slot(3, &[], None),
        pull2.for_frame(Some(&prev), 1.0).slot(3, &[], None),
    );
    assert!(
        (b[200] - 2.0 * a[200]).abs() < 1e-3 * a[200].abs(),
        "{} {}",
        a[200],
        b[200]
    );

    // An unclustered label beside it keeps its own mean pose, with or
    // without a previous frame, and the clustered one still follows it.
    let both: Labels = [
        ("style".to_string(), "happy".to_string()),
        ("content".to_string(), "wave".to_string()),
    ]
    .into_iter()
    .collect();
    let pb = p.pull(&both, 1.0).unwrap();
    let wave: Labels = [("content".to_string(), "wave".to_string())]
        .into_iter()
        .collect();
    let pw = p.pull(&wave, 1.0).unwrap();
    assert_eq!(
        peak(&pw.for_frame(Some(&prev), 1.0).slot(4, &[], None)),
        200
    );
    for s in [3, 4] {
        let (b, w, h) = (
            pb.for_frame(Some(&prev), 1.0).slot(s, &[], None),
            pw.for_frame(Some(&prev), 1.0).slot(s, &[], None),
            pull.for_frame(Some(&prev), 1.0).slot(s, &[], None),
        );
        for i in 0..360 {
            assert!((b[i] - (w[i] + h[i])).abs() < 1e-4, "slot {s} bin {i}");
        }
    }
    assert_eq!(peak(&pb.for_frame(Some(&prev), 1.0).slot(3, &[], None)), 10);
    // A frame's scale (sampling.ease) scales every slot's offsets: the
    // clustered and the unclustered labels', with a previous frame or not.
    for prev in [None, Some(&prev[..])] {
        for s in [3, 4] {
            let (whole, half) = (
                pb.for_frame(prev, 1.0).slot(s, &[], None),
                pb.for_frame(prev, 0.5).slot(s, &[], None),
            );
            for i in 0..360 {
                assert!((half[i] - 0.5 * whole[i]).abs() < 1e-4, "slot {s} bin {i}");
            }
        }
    }
}

#[test]
fn circular_mean_and_spread_go_the_short_way_round() {
    // Bins 358, 359, 0, 1, 2 of 360: mean 0, not 144.
    let s = slot_stat([358.0, 359.0, 0.0, 1.0, 2.0].into_iter(), 360.0, true);
    assert!(s.mean < 0.01 || s.mean > 359.99, "{s:?}");
    // Small spreads match the plain standard deviation (√2 ≈ 1.41),
    // floored at MIN_SPREAD.
    assert_eq!(s.spread, MIN_SPREAD);
    let wide = slot_stat([340.0, 350.0, 0.0, 10.0, 20.0].into_iter(), 360.0, true);
    // Offsets −20, −10, 0, 10, 20 bins: variance 200.
    let sd = (400.0_f64 + 100.0 + 0.0 + 100.0 + 400.0) / 5.0;
    assert!(
        (wide.spread - sd.sqrt()).abs() < 0.1,
        "{wide:?} vs {}",
        sd.sqrt()
    );
    let plain = slot_stat([10.0, 20.0, 30.0].into_iter(), 360.0, false);
    assert!((plain.mean - 20.0).abs() < 1e-12);
    assert!((plain.spread - (200.0_f64 / 3.0).sqrt()).abs() < 1e-9);
}

#[test]
fn the_tilt_is_worked_out_where_a_draw_reads_it_and_the_same_there() {
    let slots = 8;
    let mut p = two_cluster_postures(slots);
    p.tilt = BTreeMap::from([(
        "style".to_string(),
        BTreeMap::from([(
            "happy".to_string(),
            SlotStat {
                mean: 20.0,
                spread: 5.0,
            },
        )]),
    )]);
    let labels: Labels = [("style".to_string(), "happy".to_string())]
        .into_iter()
        .collect();
    let pull = p.pull(&labels, 1.0).unwrap();
    // The previous frame's root near bin 0 (the angle's low edge) and mid-range.
    for first in [2u32, 190] {
        let mut prev = vec![180u32; slots];
        prev[0] = first;
        let fp = pull.for_frame(Some(&prev), 1.0);
        let all = fp.slot(0, &[], None);
        // Radius 5, max_jump 3: the window is 5 bins either side, round the edge.
        let read = fp.slot(0, &[], Some((5, 3)));
        let mut differ = 0;
        for b in 0..360i64 {
            let d = (b - first as i64).abs();
            if d <= 5 || d.min(360 - d) <= 3 {
                assert_eq!(all[b as usize], read[b as usize], "bin {b}");
            } else if all[b as usize] != read[b as usize] {
                differ += 1;
            }
        }
        assert!(
            differ > 300,
            "{differ} bins outside the window skip the tilt"
        );
        // max_jump 0: an escape may land anywhere, so every bin is worked out.
        assert_eq!(fp.slot(0, &[], Some((5, 0))), all);
    }
    // A clip's first frame: every bin.
    let fp = pull.for_frame(None, 1.0);
    assert_eq!(fp.slot(0, &[], Some((5, 3))), fp.slot(0, &[], None));
}
