//! Velocity-tracking plots (PNG). Filled in by the plot work.
