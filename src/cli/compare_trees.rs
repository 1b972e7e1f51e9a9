//! `msnerf compare-trees --pred trees.geojson --truth truth/trees.geojson [--classes truth/classes.tif] [--json]`:
//! trees found by `export trees` against known trees (see `msnerf::products::trees::compare`). Needs no GPU.

use std::path::PathBuf;

use crate::output::raster::geotiff_read::read_geotiff;
use crate::products::trees::compare::{compare_trees, read_tree_table};

#[derive(clap::Args, Debug)]
pub struct CompareTreesArgs {
    /// The trees found (GeoJSON from `export trees`)
    #[arg(long)]
    pub pred: PathBuf,
    /// The known trees (GeoJSON in the same layout: the simulator's truth/trees.geojson)
    #[arg(long)]
    pub truth: PathBuf,
    /// A class raster (1 = ground) to count the false trees standing on open ground
    #[arg(long)]
    pub classes: Option<PathBuf>,
    /// Height tolerance, world units
    #[arg(long, value_parser = super::positive_f64, default_value_t = 0.5)]
    pub tolerance: f64,
    /// Print JSON instead of a table
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: &CompareTreesArgs) -> anyhow::Result<()> {
    let found = read_tree_table(&a.pred)?;
    let known = read_tree_table(&a.truth)?;
    let classes = a.classes.as_ref().map(|c| read_geotiff(c)).transpose()?;
    let c = compare_trees(&found, &known, classes.as_ref(), a.tolerance);
    if a.json {
        println!("{}", c.to_json());
    } else {
        print!("{}", c.table());
    }
    Ok(())
}
