//! Issue #22: the `rust-version` in Cargo.toml is true to the locked
//! dependencies: it equals the highest `rust-version` that `cargo metadata
//! --locked` reports for any of them (a lower one promises a toolchain that
//! cannot build the lock file; a higher one turns away toolchains that can).

#[test]
fn rust_version_is_what_the_locked_dependencies_need() {
    let out = std::process::Command::new(env!("CARGO"))
        .args(["metadata", "--format-version", "1", "--locked"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run cargo metadata");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let metadata: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let parse = |v: &str| -> Vec<u32> { v.split('.').map(|p| p.parse().unwrap()).collect() };
    let (needed, by) = metadata["packages"]
        .as_array()
        .unwrap()
        .iter()
        // The locked dependencies, not the workspace's own packages.
        .filter(|p| !p["source"].is_null())
        .filter_map(|p| {
            Some((
                parse(p["rust_version"].as_str()?),
                p["name"].as_str()?.to_string(),
            ))
        })
        .max()
        .expect("some dependency declares a rust-version");
    let mut ours = parse(env!("CARGO_PKG_RUST_VERSION"));
    ours.resize(needed.len(), 0);
    assert_eq!(
        ours, needed,
        "Cargo.toml says rust-version {}, the locked dependencies need {needed:?} ({by}); README.md says the same",
        env!("CARGO_PKG_RUST_VERSION")
    );
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    let text = format!("({}.{} or newer", needed[0], needed[1]);
    assert!(readme.contains(&text), "README.md should say {text:?}");
}
