//! The committed C header is exactly what cbindgen generates from `src/lib.rs` (regenerate
//! with `PSGRASP_BLESS_HEADER=1 cargo test -p psgrasp-c --test header`).
#[test]
fn the_committed_header_is_what_cbindgen_generates() {
    let dir = env!("CARGO_MANIFEST_DIR");
    let config = cbindgen::Config::from_file(format!("{dir}/cbindgen.toml")).unwrap();
    let mut generated = Vec::new();
    cbindgen::Builder::new()
        .with_src(format!("{dir}/src/lib.rs"))
        .with_config(config)
        .generate()
        .expect("cbindgen reads src/lib.rs")
        .write(&mut generated);
    let path = format!("{dir}/include/psgrasp.h");
    if std::env::var_os("PSGRASP_BLESS_HEADER").is_some() {
        std::fs::write(&path, &generated).unwrap();
    }
    let committed = std::fs::read(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "include/psgrasp.h is out of date with src/lib.rs: run \
         PSGRASP_BLESS_HEADER=1 cargo test -p psgrasp-c --test header"
    );
    let text = String::from_utf8(generated).unwrap();
    for f in [
        "psgrasp_connect(",
        "psgrasp_connect_config(",
        "psgrasp_next_pick(",
        "psgrasp_report_pick(",
        "psgrasp_get_status(",
        "psgrasp_last_error(",
        "psgrasp_disconnect(",
    ] {
        assert!(text.contains(f), "{f} missing from the header");
    }
}
