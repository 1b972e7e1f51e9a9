//! Individual trees from a canopy height model: tree tops as local maxima in a window that grows with the tree's
//! height ([`tops`]), crowns grown from the tops ([`crowns`]), and each tree's position, height, crown area and the
//! orthomosaic's band means and vegetation indices over its crown ([`attributes`]), written as GeoJSON and CSV
//! ([`table`]); [`compare`] judges them against known trees.

pub mod attributes;
pub mod compare;
pub mod crowns;
pub mod table;
pub mod tops;

pub use attributes::{describe_trees, Tree, TreeBands};
pub use crowns::{grow_crowns, CrownParams};
pub use tops::{find_tops, median_3x3, TopParams};
