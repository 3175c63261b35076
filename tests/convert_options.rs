//! The one options type of a conversion (`subdfit::convert::ConvertOptions`)
//! and its checks, which every host (`embed`, C++, Python, the CLI's
//! `batch`) runs before any work starts: τ's range is the Fitmap's own,
//! (0, 1], and the words of the mode, objective and proxy are the CLI's.

use subdfit::convert::{ConvertOptions, Mode, Proxy};
use subdfit::fit::Objective;

fn with_tau(t: f64) -> subdfit::Result<()> {
    ConvertOptions::default().with_tolerance(Some(t)).check()
}

#[test]
fn tau_range_is_the_fitmaps_own() {
    // (0, 1]: τ = 1 is a fraction the Fitmap accepts (every radius the
    // other tests allow), so the hosts accept it too.
    for ok in [1e-4, 0.01, 0.05, 0.1, 1.0] {
        with_tau(ok).unwrap();
        subdfit::analysis::fitmap::check_tolerance(ok).unwrap();
    }
    for bad in [0.0, -0.01, 1.0 + 1e-12, 2.0, f64::NAN, f64::INFINITY] {
        let e = with_tau(bad).unwrap_err().to_string();
        assert!(
            e.contains("tolerance") && e.contains("(0, 1]"),
            "{bad}: {e}"
        );
        assert!(subdfit::analysis::fitmap::check_tolerance(bad).is_err());
    }
}

#[test]
fn out_of_range_options_are_rejected_before_any_work() {
    let d = ConvertOptions::default();
    d.check().unwrap();
    let cases = [
        (d.clone().with_max_error(Some(0.0)), "max error"),
        (d.clone().with_max_error(Some(f64::NAN)), "max error"),
        (
            d.clone().with_displacement_res(Some(4097)),
            "displacement resolution",
        ),
        (d.clone().with_tessellation(Some(0)), "tessellation"),
        (d.clone().with_tessellation(Some(1025)), "tessellation"),
        (d.clone().with_proxy(Proxy::Triangles(99)), "proxy"),
    ];
    for (o, what) in cases {
        let e = o.check().unwrap_err().to_string();
        assert!(e.contains(what), "{what}: {e}");
    }
    d.clone()
        .with_max_error(Some(f64::INFINITY))
        .check()
        .unwrap();
    d.clone().with_tessellation(Some(1024)).check().unwrap();
    d.with_proxy(Proxy::Triangles(100)).check().unwrap();
}

#[test]
fn hosts_parse_the_clis_words() {
    assert_eq!("auto".parse::<Mode>(), Ok(Mode::Auto));
    assert_eq!("organic".parse::<Mode>(), Ok(Mode::Organic));
    assert_eq!("mechanical".parse::<Mode>(), Ok(Mode::Mechanical));
    assert!("Organic".parse::<Mode>().is_err());
    assert_eq!("point".parse::<Objective>(), Ok(Objective::Point));
    assert_eq!("sdm".parse::<Objective>(), Ok(Objective::Sdm));
    assert!("lsq".parse::<Objective>().is_err());
    assert_eq!("auto".parse::<Proxy>(), Ok(Proxy::Auto));
    assert_eq!("none".parse::<Proxy>(), Ok(Proxy::None));
    assert_eq!("20000".parse::<Proxy>(), Ok(Proxy::Triangles(20000)));
    assert!("99".parse::<Proxy>().is_err());
    // report.json spells them in lower case, as before.
    assert_eq!(
        serde_json::to_string(&Mode::Mechanical).unwrap(),
        "\"mechanical\""
    );
    assert_eq!(serde_json::to_string(&Objective::Sdm).unwrap(), "\"sdm\"");
}
