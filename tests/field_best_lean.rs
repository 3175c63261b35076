//! `SUBDFIT_FIELD_BEST=lean` (issue 40, session 23): the parts of BEST it
//! keeps. Its own test binary, since it sets the process's environment.

use subdfit::quad::field::draws;

#[test]
fn lean_keeps_every_part_of_best_but_two_of_its_draws() {
    for v in [
        draws::DRAWS_ENV,
        "SUBDFIT_CLEANUP_GUARDED",
        "SUBDFIT_FACES_PROJ",
        subdfit::convert::layout::MAIN_CANDIDATE_ENV,
    ] {
        std::env::remove_var(v);
    }
    std::env::set_var(draws::BEST_ENV, "lean");
    assert_eq!(draws::Best::from_env(), draws::Best::Lean);
    // The draws: scales 1 and 0.97 only.
    assert_eq!(draws::first_draws_from_env(), vec![0, 3]);
    assert_eq!(draws::draws_from_env(), 2);
    // The guarded cleanup, the judged projectability rounds and the bars'
    // score read `best_enabled` when their own switches are unset; main's
    // candidate reads it too (and needs more than one draw, as lean has).
    assert!(draws::best_enabled());
    assert_eq!(draws::Score::from_env(), draws::Score::Bars);
    assert!(subdfit::convert::layout::main_candidate());
    // A part's own switch still overrides it.
    std::env::set_var(draws::DRAWS_ENV, "4");
    assert_eq!(draws::first_draws_from_env(), vec![0, 1, 2, 3]);
    std::env::remove_var(draws::DRAWS_ENV);
    std::env::set_var(subdfit::convert::layout::MAIN_CANDIDATE_ENV, "0");
    assert!(!subdfit::convert::layout::main_candidate());
    std::env::remove_var(subdfit::convert::layout::MAIN_CANDIDATE_ENV);
    // `1` is BEST's four draws; another value is off.
    std::env::set_var(draws::BEST_ENV, "1");
    assert_eq!(draws::first_draws_from_env(), vec![0, 1, 2, 3]);
    std::env::set_var(draws::BEST_ENV, "lean2");
    assert!(!draws::best_enabled());
    assert_eq!(draws::first_draws_from_env(), vec![0]);
    std::env::remove_var(draws::BEST_ENV);
}
