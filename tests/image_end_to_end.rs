//! Issue 6, end to end: the 58-disk DEM oedometer drawn at ~100 px per
//! diameter, then detect → contacts → DIC strain → stress → infer, compared
//! with the DEM's exact contact forces (matched by grain pair / wall name).

mod e2e_pipeline;

use e2e_pipeline::{run, Setup, METHODS};
use grainforce::infer::Method;
use std::path::Path;

#[test]
fn oedometer_images_give_the_dem_forces() {
    let setup = Setup::new(100.0);
    let o = run(Path::new("fixtures/oedometer"), &setup).unwrap();
    eprintln!("{o:#?}");

    // Detection: every grain found once, centres well inside a pixel.
    assert_eq!(o.disks_found, o.grains_truth);
    assert_eq!(o.disks_matched, o.grains_truth);
    assert!(
        o.worst_centre_px < 0.5,
        "centre error {} px",
        o.worst_centre_px
    );

    // Contacts: all DEM contacts found; near misses (gap < 2 px) are extra.
    assert!(o.recall() >= 0.95, "recall {}", o.recall());
    assert!(o.precision() >= 0.7, "precision {}", o.precision());
    assert!(
        o.worst_normal_deg < 1.0,
        "normal error {}°",
        o.worst_normal_deg
    );

    // Stresses by DIC.
    assert!(o.stress_relerr < 0.05, "stress error {}", o.stress_relerr);

    // Forces: the target on the matched contacts, for every method, and
    // the extra contacts carry (almost) nothing.
    for method in METHODS {
        let e = o.relerr_of(method);
        assert!(e <= 0.10, "{method}: relerr {e}");
    }
    for (method, f) in &o.false_force {
        assert!(*f < 0.02, "{method}: force on false contacts {f}");
    }
    // Missed contacts (if any) must not hide a large force.
    assert!(
        o.relerr_all[0].1 <= 0.10,
        "qs over all DEM contacts {}",
        o.relerr_all[0].1
    );
    assert!(o.relerr_of(Method::Qs).is_finite());
}
