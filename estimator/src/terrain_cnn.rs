//! The terrain CNN's output layout and its decoding into a [`TerrainToken`], shared by the
//! trainer (`g1-train`, which builds its targets with [`targets`]) and the firmware (which
//! decodes the executor's output with [`decode`]), so both read the same seven numbers the same way.
//!
//! Outputs (in order): three class logits (flat, stairs-up, stairs-down); step height and step
//! depth in **centimetres**; the stair yaw as a unit vector `(cos θ, sin θ)` scaled by
//! [`YAW_VECTOR_SCALE`]. Centimetres and the scaled yaw vector (1 unit ≈ 1°) put SmoothL1's
//! quadratic zone at the precision that matters (sub-centimetre, about a degree), and the vector
//! encoding has no wrap-around discontinuity at ±π.
use hal::{wrap_angle, TerrainClass, TerrainToken};

/// Width of the network output.
pub const OUTPUTS: usize = 7;
/// Index of the first class logit (three logits: flat, up, down).
pub const OUT_LOGITS: usize = 0;
/// Index of the step height, cm.
pub const OUT_HEIGHT_CM: usize = 3;
/// Index of the step depth, cm.
pub const OUT_DEPTH_CM: usize = 4;
/// Index of `YAW_VECTOR_SCALE · cos θ` (then `· sin θ`).
pub const OUT_YAW_COS: usize = 5;
pub const OUT_YAW_SIN: usize = 6;
/// Scale of the yaw unit vector: a component error of one unit is about one degree.
pub const YAW_VECTOR_SCALE: f32 = 180.0 / std::f32::consts::PI;

/// Regression targets of one sample: class index, h (cm), d (cm), yaw vector (scaled).
/// For flat samples h = d = 0 and the yaw vector is meaningless (the trainer masks it).
pub fn targets(t: &TerrainToken) -> (usize, [f32; 4]) {
    let yaw = t.yaw_rad;
    (
        t.class.index(),
        [
            100.0 * t.step_height_m,
            100.0 * t.step_depth_m,
            YAW_VECTOR_SCALE * libm::cosf(yaw),
            YAW_VECTOR_SCALE * libm::sinf(yaw),
        ],
    )
}

/// The token the network's `out` stands for. `heading_rad` is the robot's heading from the state
/// estimator: the paper's flat token carries it as θ (the grid is robot-centred, so the network
/// cannot see it). Flat tokens have h = d = 0; stairs tokens clamp h and d at 0. Returns
/// `None` for a wrong-length or non-finite output (the caller holds its last token).
pub fn decode(out: &[f32], heading_rad: f32) -> Option<TerrainToken> {
    if out.len() != OUTPUTS || out.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let logits = &out[OUT_LOGITS..OUT_LOGITS + 3];
    // First maximum wins on ties, so the choice never depends on anything but the values.
    let mut best = 0;
    for k in 1..3 {
        if logits[k] > logits[best] {
            best = k;
        }
    }
    let class = TerrainClass::from_index(best)?;
    if class == TerrainClass::Flat {
        return Some(TerrainToken {
            yaw_rad: wrap_angle(heading_rad as f64) as f32,
            ..TerrainToken::FLAT
        });
    }
    Some(TerrainToken {
        class,
        step_height_m: (out[OUT_HEIGHT_CM] / 100.0).max(0.0),
        step_depth_m: (out[OUT_DEPTH_CM] / 100.0).max(0.0),
        yaw_rad: libm::atan2f(out[OUT_YAW_SIN], out[OUT_YAW_COS]),
    })
}

/// Softmax probability of the chosen class (a confidence for logs).
pub fn class_confidence(out: &[f32]) -> f32 {
    if out.len() != OUTPUTS {
        return 0.0;
    }
    let l = &out[OUT_LOGITS..OUT_LOGITS + 3];
    let m = l.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let e = [libm::expf(l[0] - m), libm::expf(l[1] - m), libm::expf(l[2] - m)];
    1.0 / (e[0] + e[1] + e[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_decode_round_trip() {
        for (class, h, d, yaw) in [
            (TerrainClass::StairsUp, 0.15f32, 0.30f32, 0.4f32),
            (TerrainClass::StairsDown, 0.21, 0.27, -3.0),
            (TerrainClass::StairsUp, 0.05, 0.45, 3.1),
        ] {
            let t = TerrainToken {
                class,
                step_height_m: h,
                step_depth_m: d,
                yaw_rad: yaw,
            };
            let (c, reg) = targets(&t);
            let mut out = [0.0f32; OUTPUTS];
            out[c] = 5.0;
            out[3..7].copy_from_slice(&reg);
            let back = decode(&out, 0.0).unwrap();
            assert_eq!(back.class, class);
            assert!((back.step_height_m - h).abs() < 1e-6);
            assert!((back.step_depth_m - d).abs() < 1e-6);
            assert!(wrap_angle((back.yaw_rad - yaw) as f64).abs() < 1e-5);
        }
    }

    #[test]
    fn flat_carries_heading_and_bad_outputs_are_rejected() {
        let mut out = [0.0f32; OUTPUTS];
        out[0] = 1.0;
        out[3] = 12.0;
        let t = decode(&out, 2.0).unwrap();
        assert_eq!(t.class, TerrainClass::Flat);
        assert_eq!((t.step_height_m, t.step_depth_m, t.yaw_rad), (0.0, 0.0, 2.0));
        out[4] = f32::NAN;
        assert!(decode(&out, 0.0).is_none());
        assert!(decode(&out[..6], 0.0).is_none());
        assert!(class_confidence(&[0.0; OUTPUTS]) > 0.33);
    }
}
