//! The one options type (`subdfit::convert::ConvertOptions`, the CLI's
//! flags) against the hosts that list options by hand: the Python binding
//! (`python/src/lib.rs`'s `Options` signature and its type stub) and the C++
//! package (`include/subdfit/subdfit.hpp`'s `struct Options`, which
//! `cpp/api/subdfit.cpp` copies field for field into the bridge). The field
//! names are taken from the type itself (its serialized form, every
//! optional field set so that none is left out), so an option added to it
//! and not to a host fails here rather than going missing in that host.

use std::path::Path;

use subdfit::convert::{ConvertOptions, Proxy};
use subdfit::displace::Reconstruction;

/// The hosts' names where they differ from the options type's (kept from
/// before this test; the rest are the same words).
const PYTHON: &[(&str, &str)] = &[
    ("target_faces", "faces_target"),
    ("objective", "fit"),
    ("no_m_fitmap", "m_fitmap"),
];
const CPP: &[(&str, &str)] = &[
    ("objective", "fit_method"),
    ("no_m_fitmap", "m_fitmap"),
    ("displacement_res", "displacement_resolution"),
];

fn fields() -> Vec<String> {
    let o = ConvertOptions::default()
        .with_displacement_samples(Some(1))
        .with_displacement_reconstruction(Reconstruction::Bspline)
        .with_exact_metrics(true)
        .with_proxy(Proxy::None);
    let v = serde_json::to_value(&o).unwrap();
    let keys: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
    // Every field serialized (none skipped as at its default): as many
    // keys as the struct has public fields.
    let src = read("src/convert/options.rs");
    let body = &src[src.find("pub struct ConvertOptions {").unwrap()..];
    let body = &body[..body.find("\n}").unwrap()];
    let declared = body.lines().filter(|l| l.starts_with("    pub ")).count();
    assert_eq!(keys.len(), declared, "serialized options {keys:?}");
    keys
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)).unwrap()
}

fn renamed<'a>(key: &'a str, table: &[(&str, &'a str)]) -> &'a str {
    table
        .iter()
        .find(|(k, _)| *k == key)
        .map_or(key, |&(_, v)| v)
}

#[test]
fn every_option_is_settable_in_python_and_cpp() {
    let binding = read("python/src/lib.rs");
    let stub = read("python/subdfit/_subdfit.pyi");
    let header = read("include/subdfit/subdfit.hpp");
    let bridge = read("cpp/api/subdfit.cpp");
    // The Options constructor's signature and the stub's class body.
    let sig = &binding[binding.find("#[pyo3(signature = (*, tolerance").unwrap()..];
    let sig = &sig[..sig.find("))]").unwrap()];
    let class = &stub[stub.find("class Options:").unwrap()..];
    let class = &class[..class.find(") -> None").unwrap()];
    let strukt = &header[header.find("struct Options {").unwrap()..];
    let strukt = &strukt[..strukt.find("};").unwrap()];
    let mut missing = Vec::new();
    for key in fields() {
        let py = renamed(&key, PYTHON);
        if !sig.contains(&format!("{py}=")) {
            missing.push(format!("python/src/lib.rs Options({py}=…)"));
        }
        if !class.contains(&format!("{py}:")) {
            missing.push(format!("_subdfit.pyi Options.{py}"));
        }
        let cpp = renamed(&key, CPP);
        if !strukt.contains(&format!(" {cpp} =")) {
            missing.push(format!("subdfit.hpp Options::{cpp}"));
        }
        if !bridge.contains(&format!("o.{cpp}")) {
            missing.push(format!("cpp/api/subdfit.cpp ffi_options: o.{cpp}"));
        }
    }
    assert!(missing.is_empty(), "options missing in a host: {missing:?}");
}
