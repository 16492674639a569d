//! The robot config: properties of the G1 itself (not of a policy), by motor slot (SDK order).
//!
//! Joint ranges are those of mjlab's G1 29-dof MJCF, which match g1_29dof_rev_1_0.urdf
//! (../shared/facts/g1_low_level.md lists the knee and ankle ones). Slots 29..35 are not fitted on
//! the G1 and have no range: targets there are never produced.
use hal::NUM_MOTORS;

/// Position range (min, max) in rad per motor slot; `None` for unfitted slots.
// The URDF's numbers, kept as written there (some happen to be close to π/6 or π/3).
#[allow(clippy::approx_constant)]
pub const G1_JOINT_RANGE: [Option<(f32, f32)>; NUM_MOTORS] = {
    const LEG_L: [(f32, f32); 6] = [
        (-2.5307, 2.8798),   // hip pitch
        (-0.5236, 2.9671),   // hip roll
        (-2.7576, 2.7576),   // hip yaw
        (-0.087267, 2.8798), // knee
        (-0.87267, 0.5236),  // ankle pitch
        (-0.2618, 0.2618),   // ankle roll
    ];
    const ARM_L: [(f32, f32); 7] = [
        (-3.0892, 2.6704),   // shoulder pitch
        (-1.5882, 2.2515),   // shoulder roll
        (-2.618, 2.618),     // shoulder yaw
        (-1.0472, 2.0944),   // elbow
        (-1.97222, 1.97222), // wrist roll
        (-1.61443, 1.61443), // wrist pitch
        (-1.61443, 1.61443), // wrist yaw
    ];
    let mut r = [None; NUM_MOTORS];
    let mut i = 0;
    while i < 6 {
        r[i] = Some(LEG_L[i]);
        // The right leg mirrors the left: hip roll's range flips sign.
        r[6 + i] = if i == 1 {
            Some((-2.9671, 0.5236))
        } else {
            Some(LEG_L[i])
        };
        i += 1;
    }
    r[12] = Some((-2.618, 2.618)); // waist yaw
    r[13] = Some((-0.52, 0.52)); // waist roll
    r[14] = Some((-0.52, 0.52)); // waist pitch
    let mut j = 0;
    while j < 7 {
        r[15 + j] = Some(ARM_L[j]);
        // Right shoulder roll mirrors the left one.
        r[22 + j] = if j == 1 {
            Some((-2.2515, 1.5882))
        } else {
            Some(ARM_L[j])
        };
        j += 1;
    }
    r
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(clippy::approx_constant)] // URDF numbers
    fn ranges_are_ordered_and_mirrored() {
        for (s, r) in G1_JOINT_RANGE.iter().enumerate().take(29) {
            let (lo, hi) = r.unwrap_or_else(|| panic!("slot {s} has no range"));
            assert!(lo < hi, "slot {s}");
        }
        assert!(G1_JOINT_RANGE[29..].iter().all(Option::is_none));
        // Knee facts from the URDF.
        assert_eq!(G1_JOINT_RANGE[3], Some((-0.087267, 2.8798)));
        assert_eq!(G1_JOINT_RANGE[7], Some((-2.9671, 0.5236)));
    }
}
