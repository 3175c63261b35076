//! `SUBDFIT_FIELD_ADAPT` is read into the options once
//! (`ConvertOptions::field_adapt`, set by `ConvertOptions::default`), and
//! nothing below reads the switch: a conversion with the switch set and
//! the option off (what `convert::adapt`'s check lays beside a doubted
//! adaptive result) is bit for bit the conversion with the switch unset.
//!
//! The only test in its binary: it sets the switch for the whole process.

use std::path::Path;

use subdfit::convert::{
    convert_in_memory, ConvertOptions, Converted, LayoutKind, Mode, FIELD_ADAPT_ENV,
};
use subdfit::quad::field::FieldOptions;

/// What `convert`'s field layout takes of the option: the natural
/// adaptivity (the sized relaxation, the caps' slope 2).
fn adaptive(fo: &FieldOptions) -> bool {
    fo.sized_relax.is_some() && fo.loop_cap_slope == 2.0
}

/// Spot at τ 10 % and the default `--max-error` (the rounds, the bracket
/// and, with the option, the following relaxation and the check): one of
/// issue 40's cases where the adaptive layout differs most from the
/// switch-off one (session 20: 357 against 171 patches).
fn convert(input: &subdfit::mesh::ValidatedMesh, opts: ConvertOptions) -> Converted {
    let opts = opts
        .with_mode(Mode::Organic)
        .with_layout(LayoutKind::Field)
        .with_tolerance(Some(0.1));
    convert_in_memory(
        input,
        &opts,
        subdfit::convert::HostRecord::default(),
        &mut |_, _| true,
    )
    .unwrap()
}

/// The control mesh's bits and the displaced surface's (its tessellated
/// points and their displacement offsets).
fn bits(c: &Converted) -> (Vec<u64>, Vec<u64>, Vec<u64>) {
    let xyz = |p: &[subdfit::DVec3]| -> Vec<u64> {
        p.iter()
            .flat_map(|v| [v.x, v.y, v.z])
            .map(f64::to_bits)
            .collect()
    };
    let s = &c.surfaces;
    let offsets = s.displaced_offsets.iter().map(|x| x.to_bits()).collect();
    (
        xyz(c.control.positions()),
        xyz(&s.displaced.positions),
        offsets,
    )
}

#[test]
fn the_option_off_is_the_switch_off_bit_for_bit() {
    std::env::remove_var(FIELD_ADAPT_ENV);
    assert!(!ConvertOptions::default().field_adapt());
    let input =
        subdfit::io::read_mesh(&Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot.ply"))
            .unwrap();
    let unset = convert(&input, ConvertOptions::default());

    std::env::set_var(FIELD_ADAPT_ENV, "1");
    assert!(ConvertOptions::default().field_adapt());
    // The option reaches the field layout's options at the natural size
    // only (`--faces` never takes the adaptivity).
    assert!(adaptive(&FieldOptions::for_convert(None, true)));
    assert!(!adaptive(&FieldOptions::for_convert(None, false)));
    assert!(!adaptive(&FieldOptions::for_convert(Some(300), true)));
    let off = convert(&input, ConvertOptions::default().with_field_adapt(false));
    assert_eq!(unset.control, off.control);
    assert!(
        bits(&unset) == bits(&off),
        "the option off differs from the switch unset"
    );
    assert!(!serde_json::to_string(&off.report.options)
        .unwrap()
        .contains("field_adapt"));

    // The option on does lay another mesh (else the comparison above
    // could not fail), and the report says so.
    let on = convert(&input, ConvertOptions::default());
    assert_ne!(unset.control.num_faces(), on.control.num_faces());
    assert!(serde_json::to_string(&on.report.options)
        .unwrap()
        .contains("\"field_adapt\":true"));
    std::env::remove_var(FIELD_ADAPT_ENV);
}
