//! The fits of one diagnosis: the baseline and every candidate family on
//! the training cells (the first stage in parallel, the second-stage
//! variants started from first-stage fits); in a K-fold design the same
//! once more per fold, whose predictions of the rows it held out become
//! the out-of-fold predictions of the full fits; and mixed-effect pairs
//! started from two single-effect fits, fitted the same way.

use super::criteria::Options;
use super::design::Design;
use super::family::{Family, Kind};
use super::fit::{dominant_level, fit, kinds, Fitted, Weights};
use super::sim::Sim;
use crate::error::Result;
use rayon::prelude::*;

/// Training and held-out cells (indices into `sim.cells`) of a design (in
/// a K-fold design both are every cell).
pub struct Split {
    /// Cells the fits see.
    pub train: Vec<usize>,
    /// Cells the fits are judged on.
    pub heldout: Vec<usize>,
}

impl Split {
    /// The cells of the design's training cases, and those of its
    /// held-out rows (not the rows a K-fold design keeps in training).
    pub fn of(sim: &Sim, design: &Design) -> Split {
        let cells = 0..sim.cells.len();
        Split {
            train: cells
                .clone()
                .filter(|&c| design.train.contains(&sim.cells[c].case))
                .collect(),
            heldout: cells
                .filter(|&c| design.holds_out(sim.cells[c].case, sim.cells[c].level))
                .collect(),
        }
    }
}

/// The progress bar (hidden without `opts.progress`).
pub fn progress_bar(opts: &Options, len: u64) -> crate::util::progress::Bar {
    let pb = crate::util::progress::bar("diagnose", len, "fits", opts.progress);
    pb.set_message("baseline");
    pb
}

/// What every fit of one run shares: the data it may see.
pub struct FitCtx<'a> {
    /// The simulated experiment.
    pub sim: &'a Sim,
    /// Cells the fits may see (indices into `sim.cells`).
    pub train_cells: Vec<usize>,
    /// Cases the fits may see (indices into the experiment's cases).
    pub train_cases: Vec<usize>,
    /// The experiment has a follower-load case (the preload family is fitted).
    pub has_follower: bool,
    /// Residual weights.
    pub w: Weights,
    /// Iteration cap of each fit.
    pub max_iterations: usize,
    /// Progress bar advanced by each fit.
    pub pb: &'a crate::util::progress::Bar,
    /// A published table's leave-one-level-out design: the effects it
    /// cannot test (see [`kinds`]); `None` otherwise.
    pub table: Option<&'a [String]>,
}

impl FitCtx<'_> {
    /// Fit families in parallel on the training cells.
    fn fit_all(&self, families: Vec<Family>) -> Result<Vec<Fitted>> {
        families
            .into_par_iter()
            .map(|f| {
                let r = fit(
                    self.sim,
                    f,
                    &self.train_cells,
                    &self.train_cases,
                    self.w,
                    self.max_iterations,
                );
                self.pb.inc(1);
                r
            })
            .collect::<Vec<Result<Fitted>>>()
            .into_iter()
            .collect()
    }

    /// Fit candidate families in parallel; a candidate whose fit fails
    /// (parameters for which some case has no equilibrium at every step
    /// the optimiser tried) is left out.
    fn fit_some(&self, families: Vec<Family>) -> Vec<Fitted> {
        families
            .into_par_iter()
            .map(|f| {
                let r = fit(
                    self.sim,
                    f,
                    &self.train_cells,
                    &self.train_cases,
                    self.w,
                    self.max_iterations,
                );
                self.pb.inc(1);
                r
            })
            .collect::<Vec<Result<Fitted>>>()
            .into_iter()
            .flatten()
            .collect()
    }

    /// The same data without the rows of fold `f`.
    fn without_fold(&self, design: &Design, f: usize) -> Self {
        let sim = self.sim;
        FitCtx {
            sim,
            train_cells: self
                .train_cells
                .iter()
                .copied()
                .filter(|&c| design.fold_of(sim.cells[c].case, sim.cells[c].level) != Some(f))
                .collect(),
            train_cases: self.train_cases.clone(),
            has_follower: self.has_follower,
            w: self.w,
            max_iterations: self.max_iterations,
            pb: self.pb,
            table: self.table,
        }
    }
}

/// Second stage, local pose: the pose family at the level that carries
/// most of the rotation-only pose fit, started from it.
fn local_pose_family(ctx: &FitCtx, rot: &Fitted, g: [f64; 3], offsets: bool) -> Result<Family> {
    let sim = ctx.sim;
    let lj = dominant_level(sim, rot, &ctx.train_cells, &ctx.train_cases, 3)?;
    let mut mask = vec![false; sim.levels.len()];
    mask[lj] = true;
    let mut loc = Family::masked(Kind::JointLocal, sim, g, mask, offsets);
    if let Some(x) = loc.x0.get_mut(..3) {
        x.copy_from_slice(&rot.x[..3]);
    }
    for k in 0..3 {
        if let (Some(v), Some(r)) = (loc.x0.get_mut(3 + k), rot.x.get(3 + 3 * lj + k)) {
            *v = *r;
        }
    }
    Ok(loc)
}

/// Second stage, pose with offsets, started from the rotation-only fit.
fn pose_offsets_family(sim: &Sim, rot: &Fitted, g: [f64; 3]) -> Family {
    let mut pose = Family::new(Kind::JointPose, sim, g);
    pose.x0[..3].copy_from_slice(&rot.x[..3]);
    for li in 0..sim.levels.len() {
        for k in 0..3 {
            pose.x0[3 + 6 * li + k] = rot.x[3 + 3 * li + k];
        }
    }
    pose
}

/// Second stage, per-level one-sided stiffening, started from the global
/// bilinear fit (a stiffer negative side, a < 0, lowers the global factor).
fn asym_per_level_family(sim: &Sim, ab: &Fitted, g: [f64; 3]) -> Family {
    let mut pl = Family::new(Kind::AsymmetricPerLevel, sim, g);
    for k in 0..3 {
        if let (Some(v), Some(r), Some(a)) = (pl.x0.get_mut(k), ab.x.get(k), ab.x.get(3 + k)) {
            *v = *r + a.min(0.0);
        }
    }
    for li in 0..sim.levels.len() {
        for k in 0..3 {
            if let (Some(v), Some(r)) = (pl.x0.get_mut(3 + 3 * li + k), ab.x.get(3 + k)) {
                *v = *r;
            }
        }
    }
    pl
}

/// Second stage, coupling at the level that carries most of the per-level
/// coupling fit, started from it.
fn local_coupling_family(ctx: &FitCtx, cp: &Fitted, g: [f64; 3]) -> Result<Family> {
    let sim = ctx.sim;
    let lc = dominant_level(sim, cp, &ctx.train_cells, &ctx.train_cases, 3)?;
    let mut mask = vec![false; sim.levels.len()];
    mask[lc] = true;
    let mut loc = Family::masked(Kind::CoupledLocal, sim, g, mask, false);
    for k in 0..6 {
        let src = if k < 3 { k } else { 3 + 3 * lc + (k - 3) };
        if let (Some(v), Some(r)) = (loc.x0.get_mut(k), cp.x.get(src)) {
            *v = *r;
        }
    }
    Ok(loc)
}

/// The second-stage families, each started from a first-stage fit.
fn stage2_families(
    ctx: &FitCtx,
    fits: &[Fitted],
    g: [f64; 3],
    offsets: bool,
) -> Result<Vec<Family>> {
    let find = |k: Kind| fits.iter().find(|f| f.family.kind == k);
    let mut out = Vec::new();
    // a table's design: no per-level variant (a held-out level's own
    // parameters are never seen)
    if ctx.table.is_some() {
        return Ok(out);
    }
    if let Some(rot) = find(Kind::JointRotation) {
        out.push(local_pose_family(ctx, rot, g, offsets)?);
        if offsets {
            out.push(pose_offsets_family(ctx.sim, rot, g));
        }
    }
    if let Some(ab) = find(Kind::AsymmetricBilinear) {
        out.push(asym_per_level_family(ctx.sim, ab, g));
    }
    if let Some(cp) = find(Kind::CoupledPerLevel) {
        out.push(local_coupling_family(ctx, cp, g)?);
    }
    Ok(out)
}

/// Baseline and every candidate family fitted on the training cells.
fn fit_families(ctx: &FitCtx, offsets: bool) -> Result<(Fitted, Vec<Fitted>)> {
    let sim = ctx.sim;
    let baseline = ctx
        .fit_all(vec![Family::new(Kind::Baseline, sim, [0.0; 3])])?
        .remove(0);
    ctx.pb.set_message("candidates");
    let g = [baseline.x[0], baseline.x[1], baseline.x[2]];
    // a table's design: the per-DoF kinds on every subset of their DoFs
    let first: Vec<Family> = kinds(ctx.has_follower, ctx.table)
        .into_iter()
        .flat_map(|k| match ctx.table {
            Some(_) => Family::dof_subsets(k, sim, g),
            None => vec![Family::new(k, sim, g)],
        })
        .collect();
    let mut fits = ctx.fit_some(first);
    ctx.pb.set_message("pose offsets, local variants");
    let more = ctx.fit_some(stage2_families(ctx, &fits, g, offsets)?);
    fits.extend(more);
    Ok((baseline, fits))
}

/// Every fit of a diagnosis: the baseline and the candidates on the
/// training cells and, in a K-fold design, on each fold.
pub struct Fits {
    /// The baseline fitted on the training cells.
    pub baseline: Fitted,
    /// The candidates fitted on the training cells.
    pub fits: Vec<Fitted>,
    /// Baseline and candidates of each fold (same order as `fits`).
    pub folds: Vec<(Fitted, Vec<Fitted>)>,
    /// Candidates left out because a fit (on all the training cells or on
    /// a fold) found no equilibrium.
    pub dropped: Vec<String>,
}

/// Store fold `f`'s predictions of the rows it held out as `full`'s
/// out-of-fold predictions.
fn merge_fold(sim: &Sim, design: &Design, f: usize, full: &mut Fitted, fold: &Fitted) {
    let rows = full.pred.len();
    let ho = full
        .heldout_pred
        .get_or_insert_with(|| vec![[f64::NAN; 6]; rows]);
    for c in &sim.cells {
        if design.fold_of(c.case, c.level) == Some(f) {
            ho[c.row] = fold.pred[c.row];
        }
    }
}

/// The baseline and every candidate on the training cells, then per fold.
pub fn fit_design(ctx: &FitCtx, design: &Design, offsets: bool) -> Result<Fits> {
    let (mut baseline, mut fits) = fit_families(ctx, offsets)?;
    // each fold: the same fits without its rows (folds in parallel)
    let mut folds: Vec<(Fitted, Vec<Fitted>)> = (0..design.folds)
        .into_par_iter()
        .map(|f| fit_families(&ctx.without_fold(design, f), offsets))
        .collect::<Vec<Result<_>>>()
        .into_iter()
        .collect::<Result<_>>()?;
    // the candidates fitted everywhere, in the full fits' order
    let everywhere = |l: &String| {
        folds
            .iter()
            .all(|(_, fs)| fs.iter().any(|f| &f.family.label() == l))
    };
    let labels: Vec<String> = fits.iter().map(|f| f.family.label()).collect();
    let dropped: Vec<String> = labels.iter().filter(|l| !everywhere(l)).cloned().collect();
    fits.retain(|f| !dropped.contains(&f.family.label()));
    for (_, fs) in folds.iter_mut() {
        let mut kept = Vec::with_capacity(fits.len());
        for f in &fits {
            let label = f.family.label();
            if let Some(i) = fs.iter().position(|x| x.family.label() == label) {
                kept.push(fs.swap_remove(i));
            }
        }
        *fs = kept;
    }
    for (f, (b, fs)) in folds.iter().enumerate() {
        merge_fold(ctx.sim, design, f, &mut baseline, b);
        for (full, fold) in fits.iter_mut().zip(fs) {
            merge_fold(ctx.sim, design, f, full, fold);
        }
    }
    Ok(Fits {
        baseline,
        fits,
        folds,
        dropped,
    })
}

/// The pair of fits `ia` and `ib` (two effects) as one family started
/// from both, fitted on the training cells and, in a K-fold design, on
/// each fold from that fold's fits.
pub fn fit_pair(
    ctx: &FitCtx,
    design: &Design,
    fits: &Fits,
    ia: usize,
    ib: usize,
) -> Result<Fitted> {
    let pair = |set: &[Fitted]| {
        let (a, b) = (&set[ia], &set[ib]);
        Family::pair(&a.family, &a.x, &b.family, &b.x)
    };
    let mut full = ctx.fit_all(vec![pair(&fits.fits)])?.remove(0);
    let folds: Vec<Fitted> = fits
        .folds
        .par_iter()
        .enumerate()
        .map(|(f, (_, fs))| {
            let c = ctx.without_fold(design, f);
            c.fit_all(vec![pair(fs)]).map(|mut v| v.remove(0))
        })
        .collect::<Vec<Result<_>>>()
        .into_iter()
        .collect::<Result<_>>()?;
    for (f, fold) in folds.iter().enumerate() {
        merge_fold(ctx.sim, design, f, &mut full, fold);
    }
    Ok(full)
}
