//! Pareto fronts on hand-made cases, and the report's pick for a time budget.

use msnerf::sweep::pareto::{candidates, pareto_front, time_front, time_front_cells};
use msnerf::sweep::report::{recommend, shared_psnr};
use msnerf::sweep::{BandScore, CellResult, TimePoint};

#[test]
fn the_front_keeps_exactly_the_undominated_points_ordered_by_cost() {
    // (time, PSNR): 1 beats 3 (cheaper and better); 4 is the most accurate; 0 the cheapest.
    let pts = [(10.0, 20.0), (20.0, 25.0), (40.0, 24.0), (30.0, 22.0), (60.0, 28.0)];
    assert_eq!(pareto_front(&pts), vec![0, 1, 4]);
    // Equal cost: only the higher score survives; equal points are all kept.
    assert_eq!(pareto_front(&[(5.0, 1.0), (5.0, 2.0)]), vec![1]);
    assert_eq!(pareto_front(&[(5.0, 2.0), (5.0, 2.0)]), vec![0, 1]);
    // Equal score: only the cheaper survives.
    assert_eq!(pareto_front(&[(6.0, 2.0), (5.0, 2.0)]), vec![1]);
    // One point, no points, and a point that beats everything.
    assert_eq!(pareto_front(&[(1.0, 1.0)]), vec![0]);
    assert!(pareto_front(&[]).is_empty());
    assert_eq!(pareto_front(&[(3.0, 1.0), (1.0, 9.0), (2.0, 5.0)]), vec![1]);
    // Non-finite measurements are never on the front and never dominate.
    assert_eq!(pareto_front(&[(1.0, f64::NAN), (2.0, 3.0), (f64::INFINITY, 9.0), (0.5, f64::INFINITY)]), vec![1]);
}

#[test]
fn the_front_is_monotone_a_staircase() {
    // Whatever the input, along the front cost and score both rise.
    let pts: Vec<(f64, f64)> = (0..50).map(|i| ((i * 37 % 23) as f64, (i * 53 % 31) as f64)).collect();
    let f = pareto_front(&pts);
    assert!(!f.is_empty());
    for w in f.windows(2) {
        let (a, b) = (pts[w[0]], pts[w[1]]);
        assert!(a.0 < b.0 && a.1 < b.1, "{a:?} then {b:?}");
    }
    for (i, p) in pts.iter().enumerate() {
        if !f.contains(&i) {
            assert!(f.iter().any(|&j| pts[j].0 <= p.0 && pts[j].1 >= p.1), "{p:?} is dominated by a front point");
        }
    }
}

fn cell(index: usize, points: &[(f64, f64)]) -> CellResult {
    CellResult {
        id: format!("c{index}"),
        index,
        label: format!("cell {index}"),
        values: vec![],
        model: "tiny".into(),
        band_names: vec!["blue".into()],
        budget_time_s: Some(60.0),
        budget_steps: None,
        steps: 10,
        elapsed_s: 60.0,
        mean_step_ms: 1.0,
        gpu_ms_per_step: 1.0,
        kernels: vec![],
        peak_gpu_bytes: 1,
        peak_cache_bytes: 1,
        parameters: 1,
        points: points
            .iter()
            .map(|&(t, p)| TimePoint {
                target_s: t,
                elapsed_s: t + 0.1,
                step: t as u64,
                psnr: p,
                ssim: 0.5,
                bands: vec![],
                geometry: None,
            })
            .collect(),
        trainer_best_eval_psnr: None,
        stopped: String::new(),
    }
}

#[test]
fn the_pick_for_a_budget_is_the_best_psnr_measured_by_then() {
    let fast = cell(0, &[(10.0, 20.0), (30.0, 22.0), (60.0, 23.0)]);
    let slow = cell(1, &[(10.0, 15.0), (30.0, 21.0), (60.0, 26.0)]);
    let r = [fast, slow];
    assert!(recommend(&r, 5.0).is_none(), "nothing was evaluated by 5 s");
    let (i, p) = recommend(&r, 10.0).unwrap();
    assert_eq!((i, p.psnr), (0, 20.0));
    let (i, p) = recommend(&r, 45.0).unwrap();
    assert_eq!((i, p.target_s), (0, 30.0));
    let (i, p) = recommend(&r, 60.0).unwrap();
    assert_eq!((i, p.psnr), (1, 26.0));
    // Past the sweep's end the best measured is the answer (the report says it was not measured that far).
    assert_eq!(recommend(&r, 900.0).unwrap().0, 1);
    // A model that got worse late keeps its best earlier point.
    let r = [cell(0, &[(10.0, 24.0), (20.0, 21.0)])];
    assert_eq!(recommend(&r, 20.0).unwrap().1.target_s, 10.0);
}

#[test]
fn cells_on_a_band_subset_are_never_picked_nor_on_the_front() {
    let six = cell(0, &[(10.0, 20.0), (30.0, 24.0)]);
    let mut three = cell(1, &[(10.0, 25.0), (30.0, 29.0)]);
    let mut six_b = cell(2, &[(10.0, 21.0), (30.0, 23.0)]);
    let all: Vec<String> = ["blue", "green", "red", "rededge1", "rededge2", "nir"].map(String::from).to_vec();
    let mut first = six;
    first.band_names = all.clone();
    six_b.band_names = all.iter().rev().cloned().collect(); // same bands, another order
    three.band_names = all[..3].to_vec();
    let r = [first, three, six_b];
    assert_eq!(candidates(&r), [true, false, true]);
    // The 3-band model has the higher all-band PSNR, but it is not a 6-band model.
    assert_eq!(recommend(&r, 10.0).unwrap().0, 2);
    assert_eq!(recommend(&r, 30.0).unwrap().0, 0);
    assert_eq!(time_front(&r), vec![(2, 0), (0, 1)]);
    assert_eq!(time_front_cells(&r), vec![0, 2]);
}

#[test]
fn shared_band_psnr_averages_the_squared_errors_not_the_decibels() {
    let band = |name: &str, psnr: f64| BandScore { name: name.into(), psnr, ssim: 0.0 };
    let p = TimePoint {
        target_s: 1.0,
        elapsed_s: 1.0,
        step: 1,
        psnr: 0.0,
        ssim: 0.0,
        bands: vec![band("blue", 20.0), band("green", 30.0), band("nir", 10.0)],
        geometry: None,
    };
    let (b, g, n) = ("blue".to_string(), "green".to_string(), "nir".to_string());
    // MSE 1e-2 and 1e-3: mean 5.5e-3.
    let want = -10.0 * 5.5e-3f64.log10();
    assert!((shared_psnr(&p, &[&b, &g]) - want).abs() < 1e-9);
    assert!((shared_psnr(&p, &[&n]) - 10.0).abs() < 1e-9);
    assert!(shared_psnr(&p, &[&"red".to_string()]).is_nan());
}
