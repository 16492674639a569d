//! A runtime's state as bytes, field by field.
//!
//! A log split into files (as rosbag2 splits bags) must replay file by file: the second file's
//! first tick depends on everything the runtime carried over from the first (the estimator's
//! filter, the observation history, the recurrent state, perception's memory, the supervisor's
//! streaks). [`Snapshot`] writes exactly that state and reads it back into a runtime built from the
//! same spec: sizes come from the spec, so a restore checks every length instead of trusting it.
//!
//! Only state is written, never configuration or weights (the log pins those by hash), nor
//! scratch buffers a step overwrites before it reads them. Little-endian, floats by their bits: a
//! restored runtime continues bit for bit.
use hal::{TerrainClass, TerrainToken};

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SnapshotError {
    #[error("the snapshot ends early ({what})")]
    Truncated { what: &'static str },
    #[error("the snapshot has {found} elements for {what}, this runtime {expected} (another spec?)")]
    Length {
        what: &'static str,
        expected: usize,
        found: u64,
    },
    #[error("the snapshot's {what} is {value}, which is not one")]
    Invalid { what: &'static str, value: u64 },
    #[error("{0} bytes follow the snapshot's end")]
    Trailing(usize),
    #[error("the snapshot's format is {found}, this g1fw reads {expected}")]
    Version { expected: u32, found: u32 },
}

/// State that can be written and read back in place.
pub trait Snapshot {
    /// Appends the state to `out`.
    fn save(&self, out: &mut Vec<u8>);
    /// Reads the state from the front of `input` (advancing it) into `self`, whose sizes (from its
    /// spec) must match the snapshot's.
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError>;
}

/// The next `N` bytes of `input`.
pub fn take<const N: usize>(input: &mut &[u8], what: &'static str) -> Result<[u8; N], SnapshotError> {
    let Some((head, rest)) = input.split_first_chunk::<N>() else {
        return Err(SnapshotError::Truncated { what });
    };
    *input = rest;
    Ok(*head)
}

/// Restores `value` from the whole of `bytes`: trailing bytes are an error.
pub fn restore_all<T: Snapshot + ?Sized>(value: &mut T, mut bytes: &[u8]) -> Result<(), SnapshotError> {
    value.restore(&mut bytes)?;
    if bytes.is_empty() {
        Ok(())
    } else {
        Err(SnapshotError::Trailing(bytes.len()))
    }
}

macro_rules! numbers {
    ($($t:ty),*) => {$(
        impl Snapshot for $t {
            fn save(&self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
                *self = <$t>::from_le_bytes(take(input, stringify!($t))?);
                Ok(())
            }
        }
    )*};
}
numbers!(u8, u16, u32, u64, i8, i16, i32, i64, f32, f64);

impl Snapshot for usize {
    fn save(&self, out: &mut Vec<u8>) {
        (*self as u64).save(out);
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        let v = u64::from_le_bytes(take(input, "usize")?);
        *self = usize::try_from(v).map_err(|_| SnapshotError::Invalid {
            what: "usize",
            value: v,
        })?;
        Ok(())
    }
}

impl Snapshot for bool {
    fn save(&self, out: &mut Vec<u8>) {
        out.push(*self as u8);
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        *self = match take::<1>(input, "bool")?[0] {
            0 => false,
            1 => true,
            v => {
                return Err(SnapshotError::Invalid {
                    what: "bool",
                    value: v as u64,
                })
            }
        };
        Ok(())
    }
}

impl<T: Snapshot, const N: usize> Snapshot for [T; N] {
    fn save(&self, out: &mut Vec<u8>) {
        self.as_slice().save(out);
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        self.as_mut_slice().restore(input)
    }
}

/// A slice keeps its length: the snapshot's must equal it.
impl<T: Snapshot> Snapshot for [T] {
    fn save(&self, out: &mut Vec<u8>) {
        self.len().save(out);
        for x in self {
            x.save(out);
        }
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        let n = u64::from_le_bytes(take(input, "length")?);
        if n != self.len() as u64 {
            return Err(SnapshotError::Length {
                what: std::any::type_name::<T>(),
                expected: self.len(),
                found: n,
            });
        }
        for x in self.iter_mut() {
            x.restore(input)?;
        }
        Ok(())
    }
}

/// A vector keeps its length (sized from the spec): the snapshot's must equal it.
impl<T: Snapshot> Snapshot for Vec<T> {
    fn save(&self, out: &mut Vec<u8>) {
        self.as_slice().save(out);
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        self.as_mut_slice().restore(input)
    }
}

impl<T: Snapshot + ?Sized> Snapshot for Box<T> {
    fn save(&self, out: &mut Vec<u8>) {
        (**self).save(out);
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        (**self).restore(input)
    }
}

/// `Some` restores into a default value when `self` is `None`.
impl<T: Snapshot + Default> Snapshot for Option<T> {
    fn save(&self, out: &mut Vec<u8>) {
        match self {
            None => out.push(0),
            Some(x) => {
                out.push(1);
                x.save(out);
            }
        }
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        match take::<1>(input, "option")?[0] {
            0 => *self = None,
            1 => self.get_or_insert_with(T::default).restore(input)?,
            v => {
                return Err(SnapshotError::Invalid {
                    what: "option",
                    value: v as u64,
                })
            }
        }
        Ok(())
    }
}

impl<A: Snapshot, B: Snapshot> Snapshot for (A, B) {
    fn save(&self, out: &mut Vec<u8>) {
        self.0.save(out);
        self.1.save(out);
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        self.0.restore(input)?;
        self.1.restore(input)
    }
}

/// Implements [`Snapshot`] for a struct as the listed fields in order (the others are
/// configuration or scratch, and stay as built).
#[macro_export]
macro_rules! snapshot_fields {
    ($ty:ty { $($field:ident),* $(,)? }) => {
        impl $crate::Snapshot for $ty {
            fn save(&self, out: &mut Vec<u8>) {
                $( $crate::Snapshot::save(&self.$field, out); )*
            }
            fn restore(&mut self, input: &mut &[u8]) -> Result<(), $crate::SnapshotError> {
                $( $crate::Snapshot::restore(&mut self.$field, input)?; )*
                Ok(())
            }
        }
    };
}

impl Snapshot for TerrainClass {
    fn save(&self, out: &mut Vec<u8>) {
        out.push(self.index() as u8);
    }
    fn restore(&mut self, input: &mut &[u8]) -> Result<(), SnapshotError> {
        let i = take::<1>(input, "terrain class")?[0];
        *self = *TerrainClass::ALL.get(i as usize).ok_or(SnapshotError::Invalid {
            what: "terrain class",
            value: i as u64,
        })?;
        Ok(())
    }
}

snapshot_fields!(TerrainToken {
    class,
    step_height_m,
    step_depth_m,
    yaw_rad
});

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Default, Debug, PartialEq)]
    struct State {
        a: f32,
        b: [u64; 3],
        c: Vec<f64>,
        d: Option<bool>,
        e: TerrainToken,
        config: u32,
    }
    snapshot_fields!(State { a, b, c, d, e });

    #[test]
    fn a_state_round_trips_bit_for_bit_and_configuration_stays() {
        let s = State {
            a: -0.0,
            b: [1, u64::MAX, 3],
            c: vec![f64::NAN, 1e-300],
            d: Some(true),
            e: TerrainToken {
                class: TerrainClass::StairsDown,
                step_height_m: 0.15,
                ..TerrainToken::FLAT
            },
            config: 7,
        };
        let mut bytes = Vec::new();
        s.save(&mut bytes);
        let mut r = State {
            c: vec![0.0; 2],
            config: 9,
            ..Default::default()
        };
        restore_all(&mut r, &bytes).unwrap();
        assert_eq!(r.a.to_bits(), s.a.to_bits());
        assert_eq!(r.c[0].to_bits(), s.c[0].to_bits());
        assert_eq!((r.b, r.c[1], r.d, r.e, r.config), (s.b, s.c[1], s.d, s.e, 9));
    }

    #[test]
    fn a_snapshot_of_another_size_truncated_or_damaged_is_refused_by_name() {
        let s = State {
            c: vec![1.0; 2],
            ..Default::default()
        };
        let mut bytes = Vec::new();
        s.save(&mut bytes);
        let mut other = State {
            c: vec![0.0; 3],
            ..Default::default()
        };
        let e = restore_all(&mut other, &bytes).unwrap_err();
        assert!(
            matches!(
                e,
                SnapshotError::Length {
                    expected: 3,
                    found: 2,
                    ..
                }
            ),
            "{e}"
        );
        let mut same = State {
            c: vec![0.0; 2],
            ..Default::default()
        };
        assert!(matches!(
            restore_all(&mut same, &bytes[..bytes.len() - 1]),
            Err(SnapshotError::Truncated { .. })
        ));
        let mut longer = bytes.clone();
        longer.push(0);
        assert_eq!(restore_all(&mut same, &longer), Err(SnapshotError::Trailing(1)));
        // The option's tag follows a (4), b (length 8 + 24) and c (8 + 16): 2 is neither None nor Some.
        let mut bad = bytes.clone();
        bad[60] = 2;
        assert!(matches!(
            restore_all(&mut same, &bad),
            Err(SnapshotError::Invalid {
                what: "option",
                value: 2
            })
        ));
    }
}
