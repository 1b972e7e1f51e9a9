//! Scale-out layer (issue 23): large flights trained as spatial blocks.
//!
//! - [`partition`]: `msnerf partition`, a grid of blocks over the ground the cameras see, each a dataset of its own;
//! - [`runner`]: `msnerf train-blocks`, every block trained by its own `msnerf train` process, resumable;
//! - [`slurm`]: `partition --slurm`, the blocks as a Slurm job array (`sbatch BLOCKS/slurm.sh`);
//! - [`slurm_time`]: each task's time limit from `msnerf bench train --json` measurements;
//! - [`merge`]: merged outputs, each world point owned by the block whose core contains it;
//! - [`merge_survey`]: the merged DSM and ortho, each grid cell rendered by the block that owns it;
//! - [`merge_render`]: views rendered by every block, blended over the overlaps by where each pixel's surface lies;
//! - [`error`]: `ScaleError`, naming the dataset, option, block or file.

pub mod error;
pub mod merge;
pub mod merge_render;
pub mod merge_survey;
pub mod partition;
pub mod runner;
pub mod slurm;
pub mod slurm_time;

pub use error::ScaleError;

/// The file that makes a folder a `msnerf partition` output.
pub const BLOCKS_FILE: &str = "blocks.json";

/// Whether `path` is a `msnerf partition` folder (its blocks' runs) rather than one run: the commands that take
/// either (`export`, `render`) decide here.
pub fn is_blocks_folder(path: &std::path::Path) -> bool {
    path.join(BLOCKS_FILE).is_file()
}
pub use partition::{partition, Block, Blocks, PartitionOptions};
