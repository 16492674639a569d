//! The bus layout: which motor slot sits on which bus with which node id and ranges, where the IMU
//! is, and the timeouts. Parsed once at start-up (this is the only place here that allocates).
use hal::{G1_MOTOR_NAMES, NUM_MOTORS};
use serde::Deserialize;

use super::MAX_MOTOR_ID;

/// Largest bus layout read (the layouts here are a few KB).
pub const MAX_LAYOUT_BYTES: usize = 1 << 20;
/// Largest MIT range (p_max, v_max, t_max, kp_max, kd_max): real motors use tens to hundreds; far
/// larger spans quantise to nothing useful and overflow the decoder's float arithmetic.
pub const MAX_MIT_RANGE: f32 = 1.0e4;

/// The MIT encoding ranges of one motor.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorRanges {
    /// Position ±p_max, rad.
    pub p_max: f32,
    /// Velocity ±v_max, rad/s.
    pub v_max: f32,
    /// Torque ±t_max, N·m.
    pub t_max: f32,
    /// kp in 0..kp_max.
    pub kp_max: f32,
    /// kd in 0..kd_max.
    pub kd_max: f32,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorConfig {
    /// unitree_hg motor slot (`hal::G1_MOTOR_NAMES` order).
    pub slot: usize,
    /// Index into `interfaces`.
    pub bus: usize,
    /// CAN node id, 1..=0x7F, unique per bus.
    pub id: u8,
    #[serde(flatten)]
    pub ranges: MotorRanges,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct ImuConfig {
    bus: usize,
}

#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLayout {
    interfaces: Vec<String>,
    motor_timeout_ticks: u32,
    tick_timeout_ms: u32,
    imu: ImuConfig,
    motor: Vec<MotorConfig>,
}

/// A validated bus layout. Motors are sorted by (bus, id): the order commands go out in.
#[derive(Clone, Debug, PartialEq)]
pub struct BusLayout {
    pub interfaces: Vec<String>,
    pub motor_timeout_ticks: u32,
    pub tick_timeout_ms: u32,
    pub imu_bus: usize,
    pub motors: Vec<MotorConfig>,
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("CAN bus layout: {}", input_file::text::for_terminal(&.0.to_string(), input_file::text::MAX_QUOTED_LINE, true))]
    Toml(toml::de::Error),
    #[error("CAN bus layout: {0}")]
    Invalid(String),
}

// Display carries the inner error's text; no `source` link, so `{:#}` chains print it once.
impl From<toml::de::Error> for ConfigError {
    fn from(e: toml::de::Error) -> Self {
        ConfigError::Toml(e)
    }
}

impl BusLayout {
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        let bad = |m: String| Err(ConfigError::Invalid(m));
        if text.len() > MAX_LAYOUT_BYTES {
            return bad(format!("more than the {MAX_LAYOUT_BYTES}-byte limit for a bus layout"));
        }
        let raw: RawLayout = toml::from_str(text)?;
        if raw.interfaces.is_empty() {
            return bad("`interfaces` is empty: name at least one bus".into());
        }
        if raw.imu.bus >= raw.interfaces.len() {
            return bad(format!(
                "imu.bus = {} but only {} interfaces are named",
                raw.imu.bus,
                raw.interfaces.len()
            ));
        }
        if raw.motor_timeout_ticks == 0 || raw.tick_timeout_ms == 0 {
            return bad("motor_timeout_ticks and tick_timeout_ms must be at least 1".into());
        }
        if raw.motor.is_empty() {
            return bad("no [[motor]] entries".into());
        }
        let mut slots = [false; NUM_MOTORS];
        for (i, m) in raw.motor.iter().enumerate() {
            let at = format!("motor[{i}] (slot {})", m.slot);
            if m.slot >= NUM_MOTORS {
                return bad(format!("{at}: slot must be below {NUM_MOTORS}"));
            }
            if std::mem::replace(&mut slots[m.slot], true) {
                return bad(format!(
                    "{at}: slot {} ({}) listed twice",
                    m.slot, G1_MOTOR_NAMES[m.slot]
                ));
            }
            if m.bus >= raw.interfaces.len() {
                return bad(format!(
                    "{at}: bus {} but only {} interfaces",
                    m.bus,
                    raw.interfaces.len()
                ));
            }
            if m.id == 0 || m.id > MAX_MOTOR_ID {
                return bad(format!("{at}: id {} outside 1..={MAX_MOTOR_ID}", m.id));
            }
            if raw.motor[..i].iter().any(|o| o.bus == m.bus && o.id == m.id) {
                return bad(format!("{at}: id {} used twice on bus {}", m.id, m.bus));
            }
            let r = m.ranges;
            for (name, v) in [
                ("p_max", r.p_max),
                ("v_max", r.v_max),
                ("t_max", r.t_max),
                ("kp_max", r.kp_max),
                ("kd_max", r.kd_max),
            ] {
                if !(v.is_finite() && v > 0.0 && v <= MAX_MIT_RANGE) {
                    return bad(format!(
                        "{at}: {name} must be a positive number up to {MAX_MIT_RANGE}, got {v}"
                    ));
                }
            }
        }
        let mut motors = raw.motor;
        motors.sort_by_key(|m| (m.bus, m.id));
        Ok(Self {
            interfaces: raw.interfaces,
            motor_timeout_ticks: raw.motor_timeout_ticks,
            tick_timeout_ms: raw.tick_timeout_ms,
            imu_bus: raw.imu.bus,
            motors,
        })
    }

    pub fn load(path: &std::path::Path) -> Result<Self, ConfigError> {
        let cannot = |e: &dyn std::fmt::Display| ConfigError::Invalid(format!("cannot read {}: {e}", path.display()));
        let text = input_file::read_text_capped(path, MAX_LAYOUT_BYTES as u64).map_err(|e| cannot(&e))?;
        Self::from_toml(&text)
    }

    /// Renames the buses (`--can vcan0,vcan1`): one name per bus of the layout, in order.
    pub fn rename_interfaces(&mut self, names: &[String]) -> Result<(), ConfigError> {
        if names.len() != self.interfaces.len() {
            return Err(ConfigError::Invalid(format!(
                "{} interface names given ({}) but the layout has {} buses ({})",
                names.len(),
                names.join(","),
                self.interfaces.len(),
                self.interfaces.join(",")
            )));
        }
        self.interfaces = names.to_vec();
        Ok(())
    }

    /// The motor with node `id` on `bus`, as an index into `motors`.
    pub fn motor_index(&self, bus: usize, id: u8) -> Option<usize> {
        self.motors.iter().position(|m| m.bus == bus && m.id == id)
    }

    /// Bit `s` set for every slot on the bus.
    pub fn slot_mask(&self) -> u64 {
        self.motors.iter().fold(0, |m, c| m | 1 << c.slot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OK: &str = r#"
interfaces = ["can0", "can1"]
motor_timeout_ticks = 10
tick_timeout_ms = 100
[imu]
bus = 0
[[motor]]
slot = 6
bus = 1
id = 1
p_max = 12.5
v_max = 37.5
t_max = 88.0
kp_max = 500.0
kd_max = 5.0
[[motor]]
slot = 0
bus = 0
id = 1
p_max = 12.5
v_max = 37.5
t_max = 88.0
kp_max = 500.0
kd_max = 5.0
"#;

    #[test]
    fn parses_and_sorts_by_bus_then_id() {
        let l = BusLayout::from_toml(OK).unwrap();
        assert_eq!(l.motors.iter().map(|m| m.slot).collect::<Vec<_>>(), [0, 6]);
        assert_eq!(l.motor_index(1, 1), Some(1));
        assert_eq!(l.slot_mask(), 1 | 1 << 6);
    }

    #[test]
    fn names_what_is_wrong() {
        let dup = OK.replace("slot = 6\nbus = 1", "slot = 6\nbus = 0");
        let mut l = BusLayout::from_toml(OK).unwrap();
        assert!(l.rename_interfaces(&["vcan0".into()]).is_err());
        l.rename_interfaces(&["vcan0".into(), "vcan1".into()]).unwrap();
        assert_eq!(l.interfaces, ["vcan0", "vcan1"]);
        let e = BusLayout::from_toml(&dup).unwrap_err().to_string();
        assert!(e.contains("id 1 used twice on bus 0"), "{e}");
        let e = BusLayout::from_toml(&OK.replace("t_max = 88.0", "t_max = -1.0"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("t_max must be a positive number"), "{e}");
        let e = BusLayout::from_toml(&OK.replace("bus = 0\n[[motor]]", "bus = 5\n[[motor]]"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("imu.bus = 5"), "{e}");
        assert!(BusLayout::from_toml("interfaces = 3").is_err());
    }
}
