//! `SUBDFIT_FIELD_ADAPT=1`'s check at a finite `--max-error`
//! (`convert::adapt`): the switch-off conversion laid beside a doubted
//! adaptive one must see the switch off on its thread, and only there and
//! only for its duration. (Its own process: the test sets the switch.)

use subdfit::quad::field::{
    natural_adaptivity, without_natural_adaptivity, FieldOptions, NATURAL_ADAPTIVITY_ENV,
};

/// What `convert`'s field layout reads of the switch: the options with
/// the natural adaptivity (the sized relaxation, the caps' slope 2).
fn adaptive(fo: &FieldOptions) -> bool {
    fo.sized_relax.is_some() && fo.loop_cap_slope == 2.0
}

#[test]
fn the_switch_is_withheld_on_the_thread_and_for_the_call_only() {
    std::env::set_var(NATURAL_ADAPTIVITY_ENV, "1");
    assert!(natural_adaptivity());
    assert!(adaptive(&FieldOptions::for_convert(None)));
    let inside = without_natural_adaptivity(|| {
        // Nested: still off inside, and off again after the inner call.
        let nested = without_natural_adaptivity(natural_adaptivity);
        let fo = FieldOptions::for_convert(None);
        (
            natural_adaptivity(),
            nested,
            adaptive(&fo),
            fo.sized_relax.is_none(),
        )
    });
    assert_eq!(inside, (false, false, false, true));
    // Restored after the call: the adaptive conversion's next read.
    assert!(natural_adaptivity());
    assert!(adaptive(&FieldOptions::for_convert(None)));
    // A panic inside does not leave it withheld on a thread that goes on
    // (a conversion's error is a `Result`, but a host may catch a panic).
    let caught = std::panic::catch_unwind(|| without_natural_adaptivity(|| panic!("inside")));
    assert!(caught.is_err());
    assert!(natural_adaptivity(), "withheld after a panic");
    // `--faces` never takes the adaptivity, with or without the check.
    assert!(!adaptive(&FieldOptions::for_convert(Some(300))));
    std::env::remove_var(NATURAL_ADAPTIVITY_ENV);
    assert!(!natural_adaptivity());
}
