use flatport::base::Board;
use flatport::base::BoardSpec;
use flatport::detect::{BoardCorners, find_corners};
fn main() {
    let rig = flatport::io::read_rig("target/tmp/zoo/sweep_41/truth_rig.json".as_ref()).unwrap();
    let cam = &rig.cameras()[0].intrinsics;
    let fold2 = cam.fold_radius2();
    println!("fold r2 {fold2:.3} r {:.3}", fold2.sqrt());
    let spec = BoardSpec::Chessboard(Board {
        rows: 3,
        cols: 7,
        square: 0.055,
    });
    let mut worst: f64 = 0.0;
    let mut fails = 0;
    let mut n = 0;
    for dir in ["water", "air"] {
        let mut paths: Vec<_> =
            std::fs::read_dir(format!("target/tmp/zoo/sweep_41/set/{dir}/cam0"))
                .unwrap()
                .map(|e| e.unwrap().path())
                .collect();
        paths.sort();
        for p in paths {
            let img = image::open(&p).unwrap().to_luma8();
            match find_corners(&img, &spec) {
                Ok(BoardCorners::Chessboard(d)) => {
                    let mut mx: f64 = 0.0;
                    let mut f = 0;
                    for q in &d.orderings[0] {
                        n += 1;
                        match cam.normalized_from_img(q) {
                            Some(u) => {
                                mx = mx.max(u.norm_squared() / fold2);
                            }
                            None => {
                                f += 1;
                                fails += 1;
                            }
                        }
                    }
                    worst = worst.max(mx);
                    println!(
                        "{dir} {}: max r2/fold2 {mx:.3}, undistort fails {f}",
                        p.file_name().unwrap().to_string_lossy()
                    );
                }
                _ => println!("{dir} {}: none", p.display()),
            }
        }
    }
    println!("worst {worst:.3} fails {fails} of {n}");
}
