//! Lidar point frames in a fixed-capacity buffer (no heap; box it once at start-up if large).

/// One return in the sensor frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LidarPoint {
    /// Metres, sensor frame.
    pub xyz: [f32; 3],
    pub reflectivity: u8,
    pub tag: u8,
    /// Offset from the frame's start time, nanoseconds.
    pub offset_ns: u32,
}

/// A lidar frame holding at most `CAP` points; points beyond capacity are counted, not stored.
#[derive(Clone, Debug)]
pub struct PointFrame<const CAP: usize> {
    pub points: [LidarPoint; CAP],
    pub len: usize,
    /// Start of the frame on the HAL's time base, nanoseconds.
    pub timestamp_ns: u64,
    /// Points that arrived but did not fit.
    pub overflow: usize,
}

impl<const CAP: usize> PointFrame<CAP> {
    pub const fn new() -> Self {
        Self {
            points: [LidarPoint {
                xyz: [0.0; 3],
                reflectivity: 0,
                tag: 0,
                offset_ns: 0,
            }; CAP],
            len: 0,
            timestamp_ns: 0,
            overflow: 0,
        }
    }

    pub fn clear(&mut self, timestamp_ns: u64) {
        self.len = 0;
        self.overflow = 0;
        self.timestamp_ns = timestamp_ns;
    }

    /// Appends a point; returns false (and counts it) when the frame is full.
    pub fn push(&mut self, p: LidarPoint) -> bool {
        if self.len < CAP {
            self.points[self.len] = p;
            self.len += 1;
            true
        } else {
            self.overflow += 1;
            false
        }
    }

    pub fn as_slice(&self) -> &[LidarPoint] {
        &self.points[..self.len]
    }

    /// Makes this frame a copy of `src` (its points only, not the whole capacity).
    pub fn copy_from(&mut self, src: &Self) {
        self.points[..src.len].copy_from_slice(&src.points[..src.len]);
        self.len = src.len;
        self.timestamp_ns = src.timestamp_ns;
        self.overflow = src.overflow;
    }
}

impl<const CAP: usize> Default for PointFrame<CAP> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_counts_overflow_instead_of_growing() {
        let mut f = PointFrame::<2>::new();
        assert!(f.push(LidarPoint::default()));
        assert!(f.push(LidarPoint::default()));
        assert!(!f.push(LidarPoint::default()));
        assert_eq!((f.len, f.overflow), (2, 1));
        f.clear(5);
        assert_eq!((f.len, f.overflow, f.timestamp_ns), (0, 0, 5));
    }
}
