//! Labels parsed from corpus file names.
//!
//! AIST++: `g{genre}_s{situation}_c{camera}_d{dancer}_m{music}_ch{choreography}`
//! (facts from the AIST++ documentation, see `shared/data/README.md`).
//! Bandai Namco: `dataset-{1,2}_{content}_{style}_{id}`.

use super::clip::Labels;

/// AIST++ genre codes and their names.
pub const AIST_GENRES: [(&str, &str); 10] = [
    ("BR", "Break"),
    ("PO", "Pop"),
    ("LO", "Lock"),
    ("MH", "Middle Hip-hop"),
    ("LH", "LA-style Hip-hop"),
    ("HO", "House"),
    ("WA", "Waack"),
    ("KR", "Krump"),
    ("JS", "Street Jazz"),
    ("JB", "Ballet Jazz"),
];

/// Tempo (BPM) of AIST++ music `m{genre}{k}`: 80..130 in steps of 10 for
/// k = 0..5, House 110..135 in steps of 5.
pub fn aist_tempo_bpm(music: &str) -> Option<u32> {
    let m = music.strip_prefix('m').unwrap_or(music);
    if m.len() != 3 || !m.is_ascii() {
        return None;
    }
    let genre = &m[..2];
    let k: u32 = m[2..].parse().ok()?;
    if k > 5 || !AIST_GENRES.iter().any(|g| g.0 == genre) {
        return None;
    }
    Some(if genre == "HO" {
        110 + 5 * k
    } else {
        80 + 10 * k
    })
}

/// The file stem (no folders, no extension).
pub fn stem(path: &str) -> &str {
    let base = path.rsplit(['/', '\\']).next().unwrap_or(path);
    match base.find('.') {
        Some(i) if i > 0 => &base[..i],
        _ => base,
    }
}

/// Labels of an AIST++ sequence name, or `None` if the name is not one.
pub fn parse_aist(name: &str) -> Option<Labels> {
    let name = stem(name);
    let parts: Vec<&str> = name.split('_').collect();
    if parts.len() != 6 {
        return None;
    }
    let genre = parts[0].strip_prefix('g')?;
    let situation = parts[1].strip_prefix('s')?;
    let camera = parts[2].strip_prefix('c')?;
    let dancer = parts[3].strip_prefix('d')?;
    let music = parts[4].strip_prefix('m')?;
    let choreo = parts[5].strip_prefix("ch")?;
    if !AIST_GENRES.iter().any(|g| g.0 == genre)
        || !matches!(situation, "BM" | "FM")
        || dancer.parse::<u32>().is_err()
        || choreo.parse::<u32>().is_err()
    {
        return None;
    }
    let mut l = Labels::new();
    l.insert("corpus".into(), "aistpp".into());
    l.insert("genre".into(), genre.into());
    l.insert("situation".into(), situation.into());
    l.insert("camera".into(), camera.into());
    l.insert("dancer".into(), format!("d{dancer}"));
    l.insert("music".into(), format!("m{music}"));
    if let Some(bpm) = aist_tempo_bpm(music) {
        l.insert("tempo_bpm".into(), bpm.to_string());
    }
    l.insert("choreography".into(), format!("ch{choreo}"));
    Some(l)
}

/// Labels of a Bandai Namco take name, or `None` if the name is not one.
pub fn parse_bandai(name: &str) -> Option<Labels> {
    let name = stem(name);
    let rest = name.strip_prefix("dataset-")?;
    let parts: Vec<&str> = rest.split('_').collect();
    if parts.len() != 4 || !matches!(parts[0], "1" | "2") || parts[3].parse::<u32>().is_err() {
        return None;
    }
    let mut l = Labels::new();
    l.insert("corpus".into(), format!("bandai-{}", parts[0]));
    l.insert("content".into(), parts[1].into());
    l.insert("style".into(), parts[2].into());
    l.insert("take".into(), parts[3].into());
    Some(l)
}

/// Labels from whichever naming scheme matches.
pub fn from_name(name: &str) -> Labels {
    parse_aist(name)
        .or_else(|| parse_bandai(name))
        .unwrap_or_default()
}

/// Every label but the take number: what takes of one content and style
/// (Bandai) share, so they can be played one after another
/// ([`super::Motion::chain`]).
pub fn but_take(labels: &Labels) -> Labels {
    let mut l = labels.clone();
    l.remove("take");
    l
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aist_names() {
        let l = parse_aist("x/gJS_sFM_cAll_d02_mJS4_ch09.pkl").unwrap();
        assert_eq!(l["genre"], "JS");
        assert_eq!(l["situation"], "FM");
        assert_eq!(l["dancer"], "d02");
        assert_eq!(l["music"], "mJS4");
        assert_eq!(l["tempo_bpm"], "120");
        assert_eq!(l["choreography"], "ch09");
        assert_eq!(aist_tempo_bpm("mHO2"), Some(120));
        assert_eq!(aist_tempo_bpm("mHO5"), Some(135));
        assert_eq!(aist_tempo_bpm("mBR0"), Some(80));
        assert_eq!(aist_tempo_bpm("mBR6"), None);
        assert!(parse_aist("gXX_sBM_cAll_d04_mBR2_ch08").is_none());
    }

    #[test]
    fn bandai_names() {
        let l = parse_bandai("dataset-2_walk-turn-left_feminine_002.bvh").unwrap();
        assert_eq!(l["content"], "walk-turn-left");
        assert_eq!(l["style"], "feminine");
        assert_eq!(l["corpus"], "bandai-2");
        assert!(parse_bandai("01_01.bvh").is_none());
    }
}
