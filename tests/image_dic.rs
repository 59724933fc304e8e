//! Digital image correlation and stresses on rendered speckle with known strain.

use grainforce::image::dic::DicOptions;
use grainforce::image::{
    measure_stresses, render_scene, render_sequence, Elasticity, PlaneCondition, RenderOptions,
    StrainOptions,
};
use grainforce::scene::{Grain, Scene};

/// Disks of radius 50 mm (100 px across at 1000 px/m) in a row, 20 mm apart.
fn row_of_disks(strains: &[[f64; 3]], elasticity: &Elasticity) -> Scene {
    let mut scene = Scene::new(2);
    for (k, e) in strains.iter().enumerate() {
        let s = elasticity.stress_from_strain(*e);
        let r = 0.05;
        let mut g = Grain::new(
            k.to_string(),
            [0.06 + 0.12 * k as f64, 0.06, 0.0],
            std::f64::consts::PI * r * r,
            [s[0], s[1], 0.0, s[2], 0.0, 0.0],
        );
        g.radius = Some(r);
        scene.grains.push(g);
    }
    scene
}

fn options(elasticity: Elasticity) -> StrainOptions {
    StrainOptions {
        elasticity,
        dic: DicOptions {
            step: 4,
            ..DicOptions::default()
        },
    }
}

#[test]
fn homogeneous_strains_from_1e_3_to_2e_2() {
    let cases: [(PlaneCondition, [[f64; 3]; 3]); 2] = [
        (
            PlaneCondition::Stress,
            [[1e-3, -5e-4, 0.0], [-5e-3, 2e-3, 3e-3], [2e-2, -1e-2, 0.0]],
        ),
        (
            PlaneCondition::Strain,
            [[-2e-2, 1e-3, 5e-3], [0.0, 0.0, 1e-2], [-3e-3, -3e-3, -1e-3]],
        ),
    ];
    for (plane, strains) in cases {
        let elasticity = Elasticity::new(5.5e6, 0.4, plane).unwrap();
        let truth = row_of_disks(&strains, &elasticity);
        let mut render = RenderOptions::new(1000.0, elasticity);
        render.noise = 0.005;
        let rendered = render_scene(&truth, &render).unwrap();
        let mut scene = truth.clone();
        for g in &mut scene.grains {
            g.stress = [0.0; 6];
        }
        let t = std::time::Instant::now();
        let report = measure_stresses(
            &rendered.reference,
            &rendered.deformed,
            &mut scene,
            &rendered.frame,
            &options(elasticity),
        )
        .unwrap();
        println!("{plane:?}: {} grains in {:?}", strains.len(), t.elapsed());
        for (k, g) in report.grains.iter().enumerate() {
            let error = (0..3)
                .map(|c| (g.strain[c] - strains[k][c]).abs())
                .fold(0.0, f64::max);
            println!(
                "  true {:?} measured [{:.6}, {:.6}, {:.6}] error {error:.1e}, {} subsets, ZNCC {:.4}",
                strains[k], g.strain[0], g.strain[1], g.strain[2], g.dic.used, g.dic.mean_zncc
            );
            assert!(error <= 2e-4, "strain error {error}");
            // The stress written into the scene is Hooke's law of the strain.
            let s = elasticity.stress_from_strain(g.strain);
            let written = &scene.grains[k].stress;
            assert_eq!([written[0], written[1], written[3]], s);
        }
    }
}

#[test]
fn rigid_translation_gives_zero_strain() {
    let elasticity = Elasticity::new(5.5e6, 0.4, PlaneCondition::Stress).unwrap();
    let before = row_of_disks(&[[0.0; 3]; 2], &elasticity);
    let mut after = before.clone();
    // 3.3 px right and 1.7 px up, at 1000 px/m.
    for g in &mut after.grains {
        g.position[0] += 3.3e-3;
        g.position[1] += 1.7e-3;
    }
    let mut render = RenderOptions::new(1000.0, elasticity);
    render.noise = 0.005;
    let rendered = render_sequence(&[before, after.clone()], &render).unwrap();
    let report = measure_stresses(
        &rendered.reference,
        &rendered.deformed[1],
        &mut after,
        &rendered.frame,
        &options(elasticity),
    )
    .unwrap();
    for g in &report.grains {
        let largest = g.strain.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        println!(
            "grain {}: translation ({:.3}, {:.3}) px, strain {:?}",
            g.id, g.dic.translation[0], g.dic.translation[1], g.strain
        );
        assert!((g.dic.translation[0] - 3.3).abs() < 0.02);
        assert!(
            (g.dic.translation[1] + 1.7).abs() < 0.02,
            "pixel y points down"
        );
        assert!(largest <= 5e-5, "strain {largest} from a rigid motion");
    }
}
