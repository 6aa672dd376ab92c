//! `docs/config.md`, the reference of every run-config and sweep-file field, generated
//! from the config structs themselves: names, types and doc comments parsed from the
//! source with `syn`, defaults from the default config serialized to TOML. The test
//! regenerates it and fails when a field (or enum variant) has no doc comment, or when
//! the committed file differs. After changing a config struct, regenerate it:
//!
//! ```sh
//! UPDATE_CONFIG_REFERENCE=1 cargo test -p agent --test config_reference
//! ```
//!
//! The generator is `config_doc/`; this file says what it reads and checks what it
//! writes.

use std::path::{Path, PathBuf};

mod config_doc;

use config_doc::generate;

/// The files that define config structs, relative to `agent/`. A field whose type is
/// defined anywhere else stops the generator with the type's name.
pub(crate) const SOURCES: &[&str] = &[
    "src/runtime/run_config/mod.rs",
    "src/core/learner_config/mod.rs",
    "src/core/learner_config/mpo.rs",
    "src/core/learner_config/vmpo.rs",
    "src/core/learner_config/network.rs",
    "src/core/learner_config/shared.rs",
    "src/env/connection.rs",
    "src/env/deadline.rs",
    "src/sweep/file.rs",
    "src/report/front/mod.rs",
    "src/core/learner_config/conditioning.rs",
];

/// What the committed reference is compared against.
const REFERENCE: &str = "../docs/config.md";

/// The environment variable that makes the test write the reference instead.
const UPDATE: &str = "UPDATE_CONFIG_REFERENCE";

fn read_sources() -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    SOURCES
        .iter()
        .map(|f| {
            let text = std::fs::read_to_string(root.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
            (f.to_string(), text)
        })
        .collect()
}

#[test]
fn docs_config_md_is_generated_from_the_documented_config_structs() {
    let (text, undocumented, no_default) = generate(&read_sources());
    assert!(
        undocumented.is_empty(),
        "config fields without a doc comment (document them in the struct): {undocumented:?}"
    );
    assert!(
        no_default.is_empty(),
        "optional config fields whose default the generator could not find: {no_default:?}"
    );
    let path: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join(REFERENCE);
    if std::env::var_os(UPDATE).is_some() {
        std::fs::write(&path, &text).unwrap();
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == text,
        "docs/config.md is stale (or missing): regenerate it with `{UPDATE}=1 cargo test -p agent --test config_reference` and commit it"
    );
}

#[test]
fn an_undocumented_field_or_variant_is_reported() {
    let mut sources = read_sources();
    let (file, text) = sources
        .iter_mut()
        .find(|(f, _)| f == "src/core/learner_config/mpo.rs")
        .unwrap();
    let documented = "    /// Table 2 \"batch size\" 512 (snippets per learner step).\n";
    assert!(
        text.contains(documented),
        "{file} changed: update this test"
    );
    *text = text.replace(documented, "");
    let (file, text) = sources
        .iter_mut()
        .find(|(f, _)| f == "src/core/learner_config/shared.rs")
        .unwrap();
    let documented =
        "    /// eta = exp(p) + 1e-8: one Adam step changes eta by a factor of about\n";
    assert!(
        text.contains(documented),
        "{file} changed: update this test"
    );
    *text = text.replace(documented, "").replace(
        "    /// exp(dual learning rate), whatever its size, so the lag after a reward is\n    /// rescaled grows only with the log of the scale.\n",
        "",
    );
    let (_, undocumented, _) = generate(&sources);
    assert_eq!(
        undocumented,
        vec![
            "learner.mpo.temperature_parameterization = \"log\" (variant TemperatureParameterization::Log)".to_string(),
            "learner.mpo.batch_size".to_string(),
            "learner.vmpo.temperature_parameterization = \"log\" (variant TemperatureParameterization::Log)".to_string(),
        ]
    );
}
