//! The figures redrawn from a run's own files (`examples/replot.rs`) are the run's: the
//! summary read back from `summary.csv` equals the run's summary bit for bit, and the
//! PNGs drawn from it equal the PNGs the run wrote, byte for byte.

mod common;

use common::{temp_dir, workspace};

use bench_harness::sweep::figures::plot_all;
use bench_harness::sweep::summary::read_summary;
use bench_harness::{RunOptions, Scenario, SummaryRow, run};

/// Every field equal, floats by their bits (NaN included).
fn same(a: &SummaryRow, b: &SummaryRow) -> bool {
    let f = |x: f64, y: f64| x.to_bits() == y.to_bits();
    let o = |x: Option<f64>, y: Option<f64>| match (x, y) {
        (Some(x), Some(y)) => f(x, y),
        (None, None) => true,
        _ => false,
    };
    let (s, t) = (&a.stats, &b.stats);
    a.sweep_value == b.sweep_value
        && a.method == b.method
        && a.quantity == b.quantity
        && a.unit == b.unit
        && a.n_failed == b.n_failed
        && s.n == t.n
        && [s.mean, s.std, s.rmse, s.median, s.min, s.max, s.range]
            .iter()
            .zip([t.mean, t.std, t.rmse, t.median, t.min, t.max, t.range])
            .all(|(&x, y)| f(x, y))
        && o(a.crb_std, b.crb_std)
        && o(a.coverage95, b.coverage95)
        && a.false_alarms == b.false_alarms
}

#[test]
fn figures_redrawn_from_summary_csv_equal_the_runs() {
    let scenario = Scenario::load(&workspace().join("scenarios/ci_regression.toml")).unwrap();
    let out = temp_dir("replot");
    let report = run(
        &scenario,
        &RunOptions {
            out: out.clone(),
            trials: Some(3),
            progress: false,
        },
    )
    .unwrap();
    let read = read_summary(&out.join("summary.csv")).unwrap();
    assert_eq!(read.len(), report.summary.len());
    for (a, b) in read.iter().zip(&report.summary) {
        assert!(same(a, b), "{a:?}\n!=\n{b:?}");
    }
    let pngs = plot_all(&scenario, &read).unwrap();
    assert_eq!(pngs.len(), 6);
    for png in pngs {
        let written = std::fs::read(out.join(&png.name)).unwrap();
        assert!(written == png.bytes, "{} differs from the run's", png.name);
    }
    let _ = std::fs::remove_dir_all(&out);
}
