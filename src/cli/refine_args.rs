//! The photometric refinement's flags, shared by `export pointcloud`, `export dsm` and `export ortho` (flattened into
//! each), and their check into [`RefineOptions`] (`msnerf::nerf::refine`; docs/geometry.md, "Photometric refinement
//! at export"). What happens to a point without photometric support differs between the products (the cloud drops
//! it, the DSM keeps the field's height), so that flag stays with each product.

use crate::nerf::refine::RefineOptions;

#[derive(clap::Args, Debug, Clone)]
pub struct RefineArgs {
    /// Skip the photometric refinement and keep the field's surface (it sits up to a metre above flat ground on the
    /// campus; docs/geometry.md). By default each consistent point (a DSM cell: its height) is searched along its
    /// ray (the vertical) for where a patch of the training images correlates best across its agreeing views
    #[arg(long)]
    pub no_refine: bool,
    /// Photometric refinement: search range each side of the field's depth, in pixel footprints
    #[arg(long, default_value_t = RefineOptions::default().range)]
    pub refine_range: usize,
    /// Photometric refinement: smallest mean normalised cross-correlation that supports a point
    #[arg(long, value_parser = super::finite_f64, default_value_t = RefineOptions::default().min_ncc)]
    pub refine_min_ncc: f64,
    /// Photometric refinement: smallest mean normalised cross-correlation that moves a point; a supported point
    /// below it keeps the field's position (a plane patch does not fit a tree crown's dome)
    #[arg(long, value_parser = super::finite_f64, default_value_t = RefineOptions::default().move_ncc)]
    pub refine_move_ncc: f64,
    /// Photometric refinement: degree of the polynomial trend removed from every patch before it is correlated, so
    /// that smooth shading (a sunlit slope, the vegetation's hotspot) does not pass for texture (0: none, 3 at most;
    /// default 0 for the cloud, 2 for the DSM)
    #[arg(long)]
    pub refine_trend: Option<usize>,
    /// Photometric refinement of DSM cells: a second sweep from another reference view must find its best score within
    /// this many pixel footprints of the first's, or the cell is not measured (0: off; default 1 for the DSM; the
    /// cloud does not use it)
    #[arg(long, value_parser = super::finite_f64)]
    pub refine_cross_check: Option<f64>,
}

impl Default for RefineArgs {
    fn default() -> Self {
        let o = RefineOptions::default();
        Self {
            no_refine: false,
            refine_range: o.range,
            refine_min_ncc: o.min_ncc,
            refine_move_ncc: o.move_ncc,
            refine_trend: None,
            refine_cross_check: None,
        }
    }
}

impl RefineArgs {
    /// The refinement these flags ask for, None with `--no-refine` or when `runs` is false (nothing to refine: an
    /// ortho alone). `consistency`: whether the multi-view check is on (its agreeing views are the
    /// refinement's partners, and `min_agree` of them may be all a point has); `keep_unsupported`: keep the points
    /// without photometric support where the field put them; `base`: the product's defaults
    /// ([`RefineOptions::default`] for the cloud, [`RefineOptions::dsm`] for the DSM). Errors name the flag.
    pub fn options(
        &self,
        runs: bool,
        consistency: bool,
        min_agree: usize,
        keep_unsupported: bool,
        base: RefineOptions,
    ) -> anyhow::Result<Option<RefineOptions>> {
        anyhow::ensure!(
            (1..=64).contains(&self.refine_range),
            "--refine-range must be between 1 and 64 footprints, got {}",
            self.refine_range
        );
        for (flag, v) in [("--refine-min-ncc", self.refine_min_ncc), ("--refine-move-ncc", self.refine_move_ncc)] {
            anyhow::ensure!(v.is_finite() && (-1.0..=1.0).contains(&v), "{flag} must be in [-1, 1], got {v}");
        }
        anyhow::ensure!(
            self.refine_move_ncc >= self.refine_min_ncc,
            "--refine-move-ncc ({}) must be at least --refine-min-ncc ({}): a point moves only where it is supported",
            self.refine_move_ncc,
            self.refine_min_ncc
        );
        let trend = self.refine_trend.unwrap_or(base.trend_degree);
        anyhow::ensure!(trend <= 3, "--refine-trend must be 0 to 3, got {trend}");
        let cross_check = match self.refine_cross_check {
            None => base.cross_check,
            Some(t) if t >= 0.0 => (t > 0.0).then_some(t),
            Some(t) => anyhow::bail!("--refine-cross-check must be a non-negative number of footprints, got {t}"),
        };
        if self.no_refine || !runs {
            return Ok(None);
        }
        anyhow::ensure!(
            consistency,
            "the photometric refinement needs the multi-view consistency check: --check-views 0 needs --no-refine"
        );
        let d = base;
        Ok(Some(RefineOptions {
            range: self.refine_range,
            min_ncc: self.refine_min_ncc,
            move_ncc: self.refine_move_ncc,
            drop_unsupported: !keep_unsupported,
            // A point has at most its agreeing views as partners, so `--min-agree 1` lets one score it.
            min_views: min_agree.clamp(1, d.min_views),
            trend_degree: trend,
            cross_check,
            ..d
        }))
    }
}
