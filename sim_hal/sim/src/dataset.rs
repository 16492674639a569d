//! Dataset generation for the terrain estimator (placeholder; being written).
