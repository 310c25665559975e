//! Tests of `motion/io/pickle.rs`.

use super::*;

#[test]
fn refuses_arbitrary_globals() {
    // cos\nsystem\n(S'ls'\ntR.  -- the classic exploit, protocol 0.
    let evil = b"cos\nsystem\n(X\x02\x00\x00\x00lstR.";
    let e = load(evil).unwrap_err();
    assert!(e.contains("refusing to call os.system"), "{e}");
}

#[test]
fn truncated_and_garbage_inputs_error() {
    assert!(load(b"").is_err());
    assert!(load(b"\x80\x04\x95").is_err());
    assert!(load(b"\x80\x04B\xff\xff\xff\x7f")
        .unwrap_err()
        .contains("truncated"));
    assert!(load(b"\x80\x04}(K\x01u.").is_err());
}

#[test]
fn exploding_copies_are_refused() {
    // L = [1]; then 64 times: L = [L, L] (memo get twice, rebuild, put
    // back). Without a cap this is 2^64 elements.
    let mut p = b"\x80\x04](K\x01eq\x000".to_vec();
    for _ in 0..64 {
        p.extend_from_slice(b"(h\x00h\x00lq\x000");
    }
    p.extend_from_slice(b"N.");
    assert!(load(&p).unwrap_err().contains("copies more data"));
    // Deep nesting is bounded by the stack limit.
    let deep = vec![b']'; 10_000];
    assert!(load(&deep).unwrap_err().contains("stack deeper"));
}

#[test]
fn small_dict() {
    // {'a': 1, 'b': [1.5]} at protocol 4, hand-assembled.
    let mut p = b"\x80\x04}\x94(\x8c\x01a\x94K\x01\x8c\x01b]\x94G".to_vec();
    p.extend_from_slice(&1.5f64.to_be_bytes());
    p.extend_from_slice(b"au.");
    let v = load(&p).unwrap();
    let d = v.as_dict().unwrap();
    assert_eq!(dict_get(d, "a"), Some(&Value::Int(1)));
    assert_eq!(
        dict_get(d, "b"),
        Some(&Value::List(vec![Value::Float(1.5)]))
    );
}
