//! The terrain CNN: [`dataset`] renders labelled BEV grids (`g1-dataset`), [`data`] holds them in
//! memory, [`model`] is the network, [`fit`] trains it, [`export`] folds it into the firmware's
//! format, [`eval`] scores the export through the firmware's executor.
pub mod data;
pub mod dataset;
pub mod eval;
pub mod export;
pub mod fit;
pub mod model;
