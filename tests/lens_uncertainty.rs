//! `report::add_lens_uncertainty` (issue 45): a calibration with the lenses held fixed reports σ
//! conditional on them; with the lenses as uncertain as their in-air calibration says, the ports'
//! and extrinsics' σ must grow by what the lenses' uncertainty moves them. The oracle is a Monte
//! Carlo run outside that code: the same observations calibrated again with each camera's lens
//! drawn from its σ, the spread of the results being the lenses' share of the variance. The
//! closed form's added variance (σ_total² − σ_conditional²) must match that spread within the
//! sampling error of 24 draws (a factor 0.5 to 2 in variance), and with lens σ near 0 the
//! conditional σ must come back.

use flatport::base::Rng;
use flatport::calib::pipeline::report::add_lens_uncertainty;
use flatport::calib::{Board, Options, SceneSpec, Target, calibrate, simulate};
use flatport::model::Rig;

/// σ of fx, fy, cx, cy, k1, k2, p1, p2, k3 given to every lens (terms at 0 are not estimated).
const LENS_STD: [f64; 9] = [1.5, 1.5, 1.0, 1.0, 2e-3, 5e-3, 1e-4, 1e-4, 1e-3];

fn example() -> Rig {
    flatport::io::read_rig("data/example_rig.json".as_ref()).unwrap()
}

/// `rig` with every lens moved by a draw of `LENS_STD` (terms at 0 stay 0).
fn perturbed(rig: &Rig, rng: &mut Rng) -> Rig {
    let cameras = rig
        .cameras()
        .iter()
        .map(|c| {
            let mut c = c.clone();
            let i = &mut c.intrinsics;
            i.fx += LENS_STD[0] * rng.normal();
            i.fy += LENS_STD[1] * rng.normal();
            i.cx += LENS_STD[2] * rng.normal();
            i.cy += LENS_STD[3] * rng.normal();
            for (d, s) in i.distortion.iter_mut().zip(&LENS_STD[4..]) {
                if *d != 0.0 {
                    *d += s * rng.normal();
                }
            }
            c
        })
        .collect();
    Rig::with_ports(cameras, rig.ports().clone()).unwrap()
}

/// (air distance m, tilt rad, right camera's rotation about y rad) of a calibrated rig.
fn figures(rig: &Rig) -> [f64; 3] {
    let port = rig.port_in_master(0);
    let r = rig.cameras()[1].cam_from_master.rotation.scaled_axis();
    [port.air_distance(), port.tilt(), r.y]
}

#[test]
fn the_lenses_share_of_the_variance_matches_a_monte_carlo_of_the_lenses() {
    let truth = example();
    let target = Target::Board(Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    });
    let scene = simulate(&truth, &SceneSpec::pair(target.clone(), 16, 0.2, 3, 0, 1)).unwrap();
    let mut options = Options::default();
    options.estimate.extrinsics = true;
    let calibration = calibrate(&truth, &scene.observations, &options).unwrap();
    assert!(calibration.report.fits);
    let rig = &calibration.rig;
    let seen = scene.observations.resolve(rig).unwrap();
    let conditional = calibration.report.clone();
    let sigma = |r: &flatport::calib::pipeline::report::Report| {
        let port = r.port();
        let right = r.cameras[1].extrinsics_std.unwrap().0;
        [port.distance.std.unwrap(), port.tilt.std.unwrap(), right[1]]
    };
    let before = sigma(&conditional);

    // Lens σ near zero: the conditional σ again.
    let mut tiny = conditional.clone();
    assert!(add_lens_uncertainty(
        &mut tiny,
        rig,
        &target,
        &seen,
        options.estimate,
        options.huber,
        &[LENS_STD.map(|s| s * 1e-6); 2],
    ));
    for (a, b) in sigma(&tiny).iter().zip(&before) {
        assert!(
            (a / b - 1.0).abs() < 1e-3,
            "{a} against the conditional {b}"
        );
    }

    let mut total = conditional.clone();
    assert!(add_lens_uncertainty(
        &mut total,
        rig,
        &target,
        &seen,
        options.estimate,
        options.huber,
        &[LENS_STD; 2],
    ));
    let after = sigma(&total);

    // Monte Carlo: the same corners, the lenses drawn from their σ.
    let mut rng = Rng::new(17);
    let draws = 24;
    let results: Vec<[f64; 3]> = (0..draws)
        .map(|_| {
            let start = perturbed(rig, &mut rng);
            let c = calibrate(&start, &scene.observations, &options).unwrap();
            figures(&c.rig)
        })
        .collect();
    let names = ["air distance", "tilt", "right rotation y"];
    for q in 0..3 {
        let mean = results.iter().map(|r| r[q]).sum::<f64>() / draws as f64;
        let spread =
            results.iter().map(|r| (r[q] - mean).powi(2)).sum::<f64>() / (draws - 1) as f64;
        let added = after[q].powi(2) - before[q].powi(2);
        eprintln!(
            "{}: σ conditional {:.3e}, with the lenses {:.3e}; added variance {added:.3e}, Monte Carlo {spread:.3e} (ratio {:.2})",
            names[q],
            before[q],
            after[q],
            added / spread
        );
        assert!(
            added > 0.5 * spread && added < 2.0 * spread,
            "{}: added variance {added:e} against the Monte Carlo's {spread:e}",
            names[q]
        );
    }
}
