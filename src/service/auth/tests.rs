//! Tests of `api/auth.rs`.

use super::*;

fn file(lines: &str) -> Result<Vec<TokenLine>, String> {
    parse_tokens("tokens.txt", lines)
}

#[test]
fn token_files_refuse_bad_lines_by_number() {
    let h = hash_token("s3cret");
    assert!(file(&format!("# c\n\na read {h}\n")).is_ok());
    let l = file(&format!("a read x,y {h}\nb read * {}\n", hash_token("z"))).unwrap();
    assert_eq!(l[0].2, Some(vec!["x".to_string(), "y".to_string()]));
    assert_eq!(l[1].2, None);
    let e = file(&format!("a read x/y {h}\n")).unwrap_err();
    assert!(e.contains("line 1") && e.contains("collection"), "{e}");
    let e = file(&format!("a read {h}\nb reed {}\n", hash_token("x"))).unwrap_err();
    assert!(e.contains("line 2") && e.contains("reed"), "{e}");
    let e = file(&format!("a read {h}\na write {}\n", hash_token("x"))).unwrap_err();
    assert!(e.contains("line 2") && e.contains("twice"), "{e}");
    let e = file("a read s3cret\n").unwrap_err();
    assert!(e.contains("line 1") && e.contains("sha256"), "{e}");
    let e = file("a read\n").unwrap_err();
    assert!(e.contains("line 1") && e.contains("fields"), "{e}");
    let e = file(&format!("a read {h}\nb write {h}\n")).unwrap_err();
    assert!(e.contains("two names"), "{e}");
}

#[test]
fn scopes_public_reads_and_buckets() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("t");
    std::fs::write(
        &p,
        format!(
            "r read {}\nw read,write {}\n",
            hash_token("rt"),
            hash_token("wt")
        ),
    )
    .unwrap();
    let a = Auth::new(&AuthConfig {
        tokens_file: Some(p.clone()),
        rate_limit: 2.0,
        rate_burst: 2.0,
        ..Default::default()
    })
    .unwrap();
    assert_eq!(a.authorize(Some("rt"), Scope::Read).unwrap().name, "r");
    assert!(matches!(
        a.authorize(Some("rt"), Scope::Write),
        Err(ApiError::PermissionDenied(_))
    ));
    assert!(matches!(
        a.authorize(None, Scope::Read),
        Err(ApiError::Unauthenticated(_))
    ));
    assert!(matches!(
        a.authorize(Some("nope"), Scope::Read),
        Err(ApiError::Unauthenticated(_))
    ));
    let w = a.authorize(Some("wt"), Scope::Write).unwrap();
    assert!(a.admit(&w, None).is_ok() && a.admit(&w, None).is_ok());
    match a.admit(&w, None) {
        Err(ApiError::RateLimited { retry_after_s, .. }) => assert_eq!(retry_after_s, 1),
        other => panic!("{other:?}"),
    }
    // Another client keeps its own bucket.
    let r = a.authorize(Some("rt"), Scope::Read).unwrap();
    assert!(a.admit(&r, None).is_ok());
    // Revoked: the line removed, the file read again.
    std::thread::sleep(Duration::from_millis(20));
    std::fs::write(&p, format!("w read,write {}\n", hash_token("wt"))).unwrap();
    let later = SystemTime::now() + Duration::from_secs(1);
    std::fs::File::options()
        .write(true)
        .open(&p)
        .unwrap()
        .set_modified(later)
        .unwrap();
    a.reload();
    assert!(matches!(
        a.authorize(Some("rt"), Scope::Read),
        Err(ApiError::Unauthenticated(_))
    ));
    let open = Auth::new(&AuthConfig {
        public_read: true,
        ..Default::default()
    })
    .unwrap();
    assert_eq!(
        open.authorize(None, Scope::Read).unwrap(),
        Principal::anonymous()
    );
    assert!(matches!(
        open.authorize(None, Scope::Write),
        Err(ApiError::PermissionDenied(_))
    ));
}
