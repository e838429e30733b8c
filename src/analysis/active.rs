//! Active points (paper §V-C, Fig. 5): the points that win at least one channel of the refiner's
//! max-pool. The paper compares the share of uncertain points (tr(Ξ) > 0.05 m²) among them with
//! the share among the network's input: if the network learned to rely on certain points, the
//! share among the active points is smaller.
//!
//! Per sample, over its refined proposals: |P_u|/|P| of the input points (the sampled rows,
//! distinct), of the active points, and the difference input − active (positive: the active
//! points are more certain than the input). The histogram of the differences over the samples is
//! Fig. 5(b), with the shares above +0.04 and below −0.04.

use std::path::Path;

use serde::Serialize;

use crate::cases::Mlod;
use crate::dataset::Dataset;
use crate::pipeline::FuseParams;
use crate::refine::RefineError;
use crate::uncertainty::UNCERTAIN_TRACE;

/// One sample's row of `active_points.csv`.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ActiveRow {
    pub sample: String,
    /// Refined proposals (with points).
    pub proposals: usize,
    pub input_points: usize,
    pub input_uncertain: f64,
    pub active_points: usize,
    pub active_uncertain: f64,
    /// input_uncertain − active_uncertain.
    pub difference: f64,
}

/// The summary of Fig. 5(b).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ActiveSummary {
    pub samples: usize,
    pub mean_difference: f64,
    /// Share of samples whose difference exceeds +0.04 / is below −0.04.
    pub above_004: f64,
    pub below_minus_004: f64,
}

/// The rows of the first `samples` samples (all when `None`) of `dataset`, under `params`.
pub fn active_points(
    dataset: &Dataset,
    mlod: &Mlod,
    params: &FuseParams,
    samples: Option<usize>,
) -> Result<Vec<ActiveRow>, RefineError> {
    let tokens: Vec<String> = dataset
        .samples()
        .into_iter()
        .map(|s| s.sample_token)
        .take(samples.unwrap_or(usize::MAX))
        .collect();
    let mut rows = Vec::new();
    for token in tokens {
        let frame = dataset.frame(&token)?;
        let run = mlod.run(&frame, params)?;
        let uncertain = |ix: &u32| {
            run.cloud
                .trace
                .get(*ix as usize)
                .is_some_and(|t| *t > UNCERTAIN_TRACE)
        };
        let (mut n_in, mut u_in, mut n_act, mut u_act, mut props) = (0usize, 0usize, 0usize, 0usize, 0usize);
        for r in run.refined.iter().filter(|r| !r.unrefined) {
            props += 1;
            n_in += r.input.len();
            u_in += r.input.iter().filter(|i| uncertain(i)).count();
            n_act += r.active.len();
            u_act += r.active.iter().filter(|i| uncertain(i)).count();
        }
        if props == 0 || n_act == 0 {
            continue;
        }
        let share = |u: usize, n: usize| u as f64 / n.max(1) as f64;
        rows.push(ActiveRow {
            sample: token,
            proposals: props,
            input_points: n_in,
            input_uncertain: share(u_in, n_in),
            active_points: n_act,
            active_uncertain: share(u_act, n_act),
            difference: share(u_in, n_in) - share(u_act, n_act),
        });
    }
    Ok(rows)
}

/// Fig. 5(b)'s numbers.
pub fn summarize(rows: &[ActiveRow]) -> ActiveSummary {
    let n = rows.len().max(1) as f64;
    ActiveSummary {
        samples: rows.len(),
        mean_difference: rows.iter().map(|r| r.difference).sum::<f64>() / n,
        above_004: rows.iter().filter(|r| r.difference > 0.04).count() as f64 / n,
        below_minus_004: rows.iter().filter(|r| r.difference < -0.04).count() as f64 / n,
    }
}

/// `active_points.csv` and `active_points.png` in `dir`.
pub fn write_report(rows: &[ActiveRow], dir: &Path, caption: &str) -> Result<ActiveSummary, RefineError> {
    let mut csv = String::from(
        "sample,proposals,input_points,input_uncertain,active_points,active_uncertain,difference\n",
    );
    for r in rows {
        csv.push_str(&format!(
            "{},{},{},{:.6},{},{:.6},{:.6}\n",
            r.sample,
            r.proposals,
            r.input_points,
            r.input_uncertain,
            r.active_points,
            r.active_uncertain,
            r.difference
        ));
    }
    crate::io::write_atomic(&dir.join("active_points.csv"), csv.as_bytes())?;
    let s = summarize(rows);
    let diffs: Vec<f64> = rows.iter().map(|r| r.difference).collect();
    let caption = format!(
        "{caption}: {:.1} % of samples > +0.04, {:.1} % < −0.04",
        100.0 * s.above_004,
        100.0 * s.below_minus_004
    );
    crate::analysis::plot::histogram_png(
        &diffs,
        (-0.3, 0.3),
        40,
        &[-0.04, 0.04],
        &caption,
        "|P_u|/|P| of the input − of the active points",
        &dir.join("active_points.png"),
    )
    .map_err(|e| RefineError::BadParameter(e.to_string()))?;
    Ok(s)
}
