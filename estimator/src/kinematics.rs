//! G1 leg kinematics: foot positions and Jacobians relative to the pelvis, built at start-up from
//! the robot's MJCF (the one source of the kinematic parameters; nothing is typed in here).
//!
//! Each leg is the chain of bodies from the pelvis down to `{side}_ankle_roll_link`, with the six
//! hinges of the unitree_hg motor order (hip pitch, hip roll, hip yaw, knee, ankle pitch, ankle
//! roll). The **foot point** is the sole centre in the ankle-roll frame: the site `{side}_foot`
//! when the model has one (the 29-dof mjlab model), else the centroid of the foot's collision
//! spheres lowered by their radius (the 12-dof unitree_rl_gym model). On flat ground a foot in
//! contact has its foot point at ground height.
use nalgebra::{Matrix3x6, Matrix6, UnitQuaternion, Vector3};

/// The two legs, in motor-slot order (left = slots 0..6, right = 6..12).
pub const LEGS: [Side; 2] = [Side::Left, Side::Right];

/// Leg joint names after the side prefix, in unitree_hg motor order.
pub const LEG_JOINTS: [&str; 6] = [
    "hip_pitch_joint",
    "hip_roll_joint",
    "hip_yaw_joint",
    "knee_joint",
    "ankle_pitch_joint",
    "ankle_roll_joint",
];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    Left,
    Right,
}

impl Side {
    pub fn prefix(self) -> &'static str {
        match self {
            Side::Left => "left",
            Side::Right => "right",
        }
    }
    /// First motor slot of this leg.
    pub fn first_slot(self) -> usize {
        match self {
            Side::Left => 0,
            Side::Right => 6,
        }
    }
    pub fn index(self) -> usize {
        self as usize
    }
}

#[derive(Debug, thiserror::Error)]
pub enum KinematicsError {
    #[error("MJCF is not valid XML: {0}")]
    Xml(String),
    #[error("MJCF has no body named '{0}'")]
    MissingBody(String),
    #[error("MJCF has no joint named '{0}'")]
    MissingJoint(String),
    #[error("MJCF: '{name}' has a bad {attr} attribute '{value}' (expected {expected} numbers)")]
    BadAttribute {
        name: String,
        attr: &'static str,
        value: String,
        expected: usize,
    },
    #[error("MJCF: {0}")]
    Unsupported(String),
}

/// One body of a leg chain: its frame relative to its parent and the hinge it carries.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Link {
    pos: Vector3<f64>,
    rot: UnitQuaternion<f64>,
    /// Hinge anchor and unit axis in the body frame, and its index 0..6 in the leg.
    joint: Option<(Vector3<f64>, Vector3<f64>, usize)>,
}

/// Kinematics of one leg.
#[derive(Clone, Debug, PartialEq)]
pub struct Leg {
    side: Side,
    /// Pelvis (exclusive) → ankle roll link (inclusive). At most 8 bodies (fixed frames allowed).
    links: [Option<Link>; 8],
    /// Foot point in the ankle-roll frame, m.
    foot: Vector3<f64>,
    /// Lowest points of the foot's collision geoms (sphere / capsule-end centres lowered by the
    /// radius along the foot's z), ankle-roll frame; the first `sole_len` are used.
    sole: [Vector3<f64>; MAX_SOLE_POINTS],
    sole_len: usize,
}

/// Sole points kept per foot (the 29-dof foot has 7 capsules, 14 ends).
pub const MAX_SOLE_POINTS: usize = 16;

/// A leg's pose for one joint configuration: foot point, hinge anchors and axes, all in the pelvis
/// frame.
#[derive(Clone, Copy, Debug)]
pub struct LegPose {
    pub foot: Vector3<f64>,
    /// Origin of the ankle-roll link in the pelvis frame.
    pub ankle: Vector3<f64>,
    /// Orientation of the ankle-roll link (the foot) in the pelvis frame.
    pub foot_rot: UnitQuaternion<f64>,
    anchors: [Vector3<f64>; 6],
    axes: [Vector3<f64>; 6],
    sole: [Vector3<f64>; MAX_SOLE_POINTS],
    sole_len: usize,
}

impl LegPose {
    /// The sole's lowest point along world z for a base orientation `rot`, relative to the base
    /// (m); the foot point's when the model gives no collision geometry.
    pub fn sole_min_z(&self, rot: &UnitQuaternion<f64>) -> f64 {
        if self.sole_len == 0 {
            return (rot * self.foot).z;
        }
        self.sole[..self.sole_len]
            .iter()
            .map(|p| (rot * p).z)
            .fold(f64::INFINITY, f64::min)
    }

    /// Linear (3×6) Jacobian of the foot point w.r.t. the leg's joint angles, pelvis frame.
    pub fn position_jacobian(&self) -> Matrix3x6<f64> {
        let mut j = Matrix3x6::zeros();
        for i in 0..6 {
            j.set_column(i, &self.axes[i].cross(&(self.foot - self.anchors[i])));
        }
        j
    }

    /// Geometric (6×6) Jacobian of the foot frame at the foot point: rows 0..3 linear velocity,
    /// 3..6 angular velocity, pelvis frame.
    pub fn spatial_jacobian(&self) -> Matrix6<f64> {
        let mut j = Matrix6::zeros();
        for i in 0..6 {
            let lin = self.axes[i].cross(&(self.foot - self.anchors[i]));
            j.fixed_view_mut::<3, 1>(0, i).copy_from(&lin);
            j.fixed_view_mut::<3, 1>(3, i).copy_from(&self.axes[i]);
        }
        j
    }
}

impl Leg {
    pub fn side(&self) -> Side {
        self.side
    }
    /// The foot point in the ankle-roll frame, m.
    pub fn foot_offset(&self) -> Vector3<f64> {
        self.foot
    }

    /// Forward kinematics for joint angles `q` (leg order).
    pub fn pose(&self, q: &[f64; 6]) -> LegPose {
        let mut pos = Vector3::zeros();
        let mut rot = UnitQuaternion::identity();
        let mut anchors = [Vector3::zeros(); 6];
        let mut axes = [Vector3::zeros(); 6];
        for link in self.links.iter().flatten() {
            pos += rot * link.pos;
            rot *= link.rot;
            if let Some((anchor, axis, i)) = link.joint {
                let a = pos + rot * anchor;
                let w = rot * axis;
                anchors[i] = a;
                axes[i] = w;
                // Rotation about an axis through the anchor: the anchor stays put.
                let r = crate::attitude::quat_from_scaled_axis(axis * q[i]);
                pos = a + (rot * r) * (-anchor);
                rot *= r;
            }
        }
        let mut sole = [Vector3::zeros(); MAX_SOLE_POINTS];
        for (out, p) in sole.iter_mut().zip(&self.sole[..self.sole_len]) {
            *out = pos + rot * p;
        }
        LegPose {
            foot: pos + rot * self.foot,
            ankle: pos,
            foot_rot: rot,
            anchors,
            axes,
            sole,
            sole_len: self.sole_len,
        }
    }

    /// Foot point in the pelvis frame.
    pub fn foot_position(&self, q: &[f64; 6]) -> Vector3<f64> {
        self.pose(q).foot
    }
}

/// Largest MJCF file read (the G1's models are under 100 KB; meshes are separate files).
pub const MAX_MJCF_BYTES: u64 = 16 << 20;

/// Both legs of the G1.
#[derive(Clone, Debug, PartialEq)]
pub struct LegKinematics {
    legs: [Leg; 2],
}

impl LegKinematics {
    /// Reads an MJCF file (see [`LegKinematics::from_mjcf`]).
    pub fn from_mjcf_file(path: &std::path::Path) -> Result<Self, KinematicsError> {
        let cannot = |e: &dyn std::fmt::Display| KinematicsError::Xml(format!("cannot read {}: {e}", path.display()));
        let text = input_file::read_text_capped(path, MAX_MJCF_BYTES).map_err(|e| cannot(&e))?;
        Self::from_mjcf(&text)
    }

    /// Builds both leg chains from MJCF text. Supports what the G1 models use: body `pos` /
    /// `quat`, hinge `pos` / `axis`; refuses other orientation forms rather than guess.
    pub fn from_mjcf(xml: &str) -> Result<Self, KinematicsError> {
        let doc = roxmltree::Document::parse(xml).map_err(|e| KinematicsError::Xml(e.to_string()))?;
        if doc.descendants().any(|n| {
            n.has_tag_name("default") && n.children().any(|c| c.has_tag_name("joint") && c.has_attribute("axis"))
        }) {
            return Err(KinematicsError::Unsupported(
                "joint axes set through <default> classes are not resolved; give each leg joint an explicit axis"
                    .into(),
            ));
        }
        let left = leg_from_doc(&doc, Side::Left)?;
        let right = leg_from_doc(&doc, Side::Right)?;
        Ok(Self { legs: [left, right] })
    }

    pub fn leg(&self, side: Side) -> &Leg {
        &self.legs[side.index()]
    }
}

fn body_name<'a>(n: roxmltree::Node<'a, '_>) -> &'a str {
    n.attribute("name").unwrap_or("<unnamed body>")
}

fn parse_vec<const N: usize>(
    n: roxmltree::Node,
    attr: &'static str,
    default: [f64; N],
) -> Result<[f64; N], KinematicsError> {
    let Some(text) = n.attribute(attr) else {
        return Ok(default);
    };
    let bad = || KinematicsError::BadAttribute {
        name: n.attribute("name").unwrap_or(n.tag_name().name()).to_string(),
        attr,
        value: text.to_string(),
        expected: N,
    };
    let mut out = [0.0f64; N];
    let mut it = text.split_whitespace();
    for v in out.iter_mut() {
        *v = it.next().ok_or_else(bad)?.parse().map_err(|_| bad())?;
        if !v.is_finite() {
            return Err(bad());
        }
    }
    if it.next().is_some() {
        return Err(bad());
    }
    Ok(out)
}

fn leg_from_doc(doc: &roxmltree::Document, side: Side) -> Result<Leg, KinematicsError> {
    let p = side.prefix();
    let ankle_name = format!("{p}_ankle_roll_link");
    let ankle = doc
        .descendants()
        .find(|n| n.has_tag_name("body") && n.attribute("name") == Some(ankle_name.as_str()))
        .ok_or(KinematicsError::MissingBody(ankle_name.clone()))?;

    // Walk up to the pelvis, collecting the chain.
    let mut chain = Vec::new();
    let mut node = ankle;
    loop {
        if node.attribute("name") == Some("pelvis") {
            break;
        }
        if !node.has_tag_name("body") {
            return Err(KinematicsError::MissingBody(format!("pelvis (above {ankle_name})")));
        }
        chain.push(node);
        node = node
            .parent_element()
            .ok_or_else(|| KinematicsError::MissingBody(format!("pelvis (above {ankle_name})")))?;
    }
    chain.reverse();
    if chain.len() > 8 {
        return Err(KinematicsError::Unsupported(format!(
            "{} bodies between the pelvis and {ankle_name}; at most 8 are supported",
            chain.len()
        )));
    }

    let mut links = [None; 8];
    let mut seen = [false; 6];
    for (slot, body) in links.iter_mut().zip(&chain) {
        for attr in ["euler", "axisangle", "xyaxes", "zaxis"] {
            if body.has_attribute(attr) {
                return Err(KinematicsError::Unsupported(format!(
                    "body '{}' gives its orientation as {attr}; only quat is supported",
                    body_name(*body)
                )));
            }
        }
        let pos = parse_vec(*body, "pos", [0.0; 3])?;
        let [w, x, y, z] = parse_vec(*body, "quat", [1.0, 0.0, 0.0, 0.0])?;
        let q = nalgebra::Quaternion::new(w, x, y, z);
        if q.norm() < 1e-9 {
            return Err(KinematicsError::Unsupported(format!(
                "body '{}' has a zero quat",
                body_name(*body)
            )));
        }
        let joints: Vec<_> = body.children().filter(|c| c.has_tag_name("joint")).collect();
        let joint = match joints.as_slice() {
            [] => None,
            [j] => {
                let name = j.attribute("name").unwrap_or("");
                let idx = LEG_JOINTS
                    .iter()
                    .position(|s| name == format!("{p}_{s}"))
                    .ok_or_else(|| {
                        KinematicsError::Unsupported(format!(
                            "joint '{name}' in leg body '{}' is not one of the six {p} leg joints",
                            body_name(*body)
                        ))
                    })?;
                if j.attribute("type").is_some_and(|t| t != "hinge") {
                    return Err(KinematicsError::Unsupported(format!(
                        "leg joint '{name}' is not a hinge"
                    )));
                }
                let anchor = Vector3::from(parse_vec(*j, "pos", [0.0; 3])?);
                let axis = Vector3::from(parse_vec(*j, "axis", [0.0, 0.0, 1.0])?);
                if axis.norm() < 1e-9 {
                    return Err(KinematicsError::Unsupported(format!(
                        "leg joint '{name}' has a zero axis"
                    )));
                }
                seen[idx] = true;
                Some((anchor, axis.normalize(), idx))
            }
            _ => {
                return Err(KinematicsError::Unsupported(format!(
                    "leg body '{}' carries {} joints; one is supported",
                    body_name(*body),
                    joints.len()
                )))
            }
        };
        *slot = Some(Link {
            pos: Vector3::from(pos),
            rot: UnitQuaternion::from_quaternion(q),
            joint,
        });
    }
    if let Some(i) = seen.iter().position(|s| !s) {
        return Err(KinematicsError::MissingJoint(format!("{p}_{}", LEG_JOINTS[i])));
    }
    // The joint order along the chain must be the motor order.
    let order: Vec<usize> = links.iter().flatten().filter_map(|l| l.joint.map(|j| j.2)).collect();
    if order != [0, 1, 2, 3, 4, 5] {
        return Err(KinematicsError::Unsupported(format!(
            "the {p} leg's joints run in order {order:?} from the pelvis, not hip pitch, roll, yaw, knee, ankle pitch, roll"
        )));
    }

    let (sole, sole_len) = sole_points(doc, ankle)?;
    Ok(Leg {
        side,
        links,
        foot: foot_point(ankle, p, &sole[..sole_len])?,
        sole,
        sole_len,
    })
}

/// `size` of a geom: its own attribute, else the one its `class` default sets.
fn geom_size(doc: &roxmltree::Document, g: roxmltree::Node) -> Result<Option<f64>, KinematicsError> {
    if g.has_attribute("size") {
        let [r] = parse_vec(g, "size", [0.0])?;
        return Ok(Some(r));
    }
    let Some(class) = g.attribute("class") else {
        return Ok(None);
    };
    for d in doc
        .descendants()
        .filter(|n| n.has_tag_name("default") && n.attribute("class") == Some(class))
    {
        if let Some(dg) = d.children().find(|c| c.has_tag_name("geom") && c.has_attribute("size")) {
            let [r] = parse_vec(dg, "size", [0.0])?;
            return Ok(Some(r));
        }
    }
    Ok(None)
}

/// The foot's lowest collision points: sphere centres and capsule ends (`fromto`), each lowered
/// by its radius along the ankle frame's z. Visual-only geoms (`contype="0"`, meshes) are skipped.
fn sole_points(
    doc: &roxmltree::Document,
    ankle: roxmltree::Node,
) -> Result<([Vector3<f64>; MAX_SOLE_POINTS], usize), KinematicsError> {
    let mut out = [Vector3::zeros(); MAX_SOLE_POINTS];
    let mut n = 0;
    let mut push = |p: Vector3<f64>| {
        if n < MAX_SOLE_POINTS {
            out[n] = p;
            n += 1;
        }
    };
    for g in ankle.children().filter(|c| c.has_tag_name("geom")) {
        if g.attribute("contype") == Some("0") || g.has_attribute("mesh") {
            continue;
        }
        let Some(r) = geom_size(doc, g)? else { continue };
        let down = Vector3::new(0.0, 0.0, r);
        if g.has_attribute("fromto") {
            let [a, b, c, d, e, f] = parse_vec(g, "fromto", [0.0; 6])?;
            push(Vector3::new(a, b, c) - down);
            push(Vector3::new(d, e, f) - down);
        } else if g.attribute("type").is_none_or(|t| t == "sphere") {
            push(Vector3::from(parse_vec(g, "pos", [0.0; 3])?) - down);
        }
    }
    Ok((out, n))
}

/// The sole centre in the ankle-roll frame (see the module doc): the `{p}_foot` site, else the
/// centroid of the sole points at their lowest height.
fn foot_point(ankle: roxmltree::Node, p: &str, sole: &[Vector3<f64>]) -> Result<Vector3<f64>, KinematicsError> {
    let site = format!("{p}_foot");
    if let Some(s) = ankle
        .children()
        .find(|c| c.has_tag_name("site") && c.attribute("name") == Some(site.as_str()))
    {
        return Ok(Vector3::from(parse_vec(s, "pos", [0.0; 3])?));
    }
    if sole.is_empty() {
        return Err(KinematicsError::Unsupported(format!(
            "no site '{site}' and no collision spheres or capsules on {p}_ankle_roll_link to place the foot point"
        )));
    }
    let c = sole.iter().sum::<Vector3<f64>>() / sole.len() as f64;
    let low = sole.iter().map(|v| v.z).fold(f64::INFINITY, f64::min);
    Ok(Vector3::new(c.x, c.y, low))
}

/// A toy two-legged MJCF (0.4 m thigh and shank) for unit tests.
#[cfg(test)]
pub(crate) const TEST_LEGS_MJCF: &str = tests::TWO_LINK;

#[cfg(test)]
mod tests {
    use super::*;

    pub(super) const TWO_LINK: &str = r#"<mujoco><worldbody><body name="pelvis">
      <body name="left_hip_pitch_link" pos="0 0.1 0"><joint name="left_hip_pitch_joint" axis="0 1 0"/>
       <body name="left_hip_roll_link"><joint name="left_hip_roll_joint" axis="1 0 0"/>
        <body name="left_hip_yaw_link"><joint name="left_hip_yaw_joint"/>
         <body name="left_knee_link" pos="0 0 -0.4"><joint name="left_knee_joint" axis="0 1 0"/>
          <body name="left_ankle_pitch_link" pos="0 0 -0.4"><joint name="left_ankle_pitch_joint" axis="0 1 0"/>
           <body name="left_ankle_roll_link"><joint name="left_ankle_roll_joint" axis="1 0 0"/>
             <geom size="0.01" pos="0.1 0 -0.04"/><geom size="0.01" pos="-0.1 0 -0.04"/>
             <geom type="mesh" mesh="foot"/>
      </body></body></body></body></body></body>
      <body name="right_hip_pitch_link" pos="0 -0.1 0"><joint name="right_hip_pitch_joint" axis="0 1 0"/>
       <body name="right_hip_roll_link"><joint name="right_hip_roll_joint" axis="1 0 0"/>
        <body name="right_hip_yaw_link"><joint name="right_hip_yaw_joint"/>
         <body name="right_knee_link" pos="0 0 -0.4"><joint name="right_knee_joint" axis="0 1 0"/>
          <body name="right_ankle_pitch_link" pos="0 0 -0.4"><joint name="right_ankle_pitch_joint" axis="0 1 0"/>
           <body name="right_ankle_roll_link"><joint name="right_ankle_roll_joint" axis="1 0 0"/>
             <site name="right_foot" pos="0 0 -0.05"/>
      </body></body></body></body></body></body>
    </body></worldbody></mujoco>"#;

    #[test]
    fn straight_leg_and_bent_knee() {
        let k = LegKinematics::from_mjcf(TWO_LINK).unwrap();
        let l = k.leg(Side::Left);
        assert!((l.foot_offset() - Vector3::new(0.0, 0.0, -0.05)).norm() < 1e-12);
        let f = l.foot_position(&[0.0; 6]);
        assert!((f - Vector3::new(0.0, 0.1, -0.85)).norm() < 1e-12, "{f}");
        // Knee bent 90°: the shank (0.4) and foot (0.05) point along -x... rotation about +y takes
        // -z to -x.
        let f = l.foot_position(&[0.0, 0.0, 0.0, std::f64::consts::FRAC_PI_2, 0.0, 0.0]);
        assert!((f - Vector3::new(-0.45, 0.1, -0.4)).norm() < 1e-12, "{f}");
        let r = k.leg(Side::Right).foot_position(&[0.0; 6]);
        assert!((r - Vector3::new(0.0, -0.1, -0.85)).norm() < 1e-12, "{r}");
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let k = LegKinematics::from_mjcf(TWO_LINK).unwrap();
        let l = k.leg(Side::Left);
        let q = [0.3, -0.2, 0.1, 0.8, -0.4, 0.15];
        let pose = l.pose(&q);
        let j = pose.position_jacobian();
        let js = pose.spatial_jacobian();
        for i in 0..6 {
            let mut qp = q;
            qp[i] += 1e-6;
            let fd = (l.foot_position(&qp) - pose.foot) / 1e-6;
            assert!((fd - j.column(i)).norm() < 1e-5, "column {i}");
            assert!((fd - js.fixed_view::<3, 1>(0, i)).norm() < 1e-5);
            // Angular part: the change of the foot orientation.
            let dr = l.pose(&qp).foot_rot * pose.foot_rot.inverse();
            let w = dr.scaled_axis() / 1e-6;
            assert!((w - js.fixed_view::<3, 1>(3, i)).norm() < 1e-5, "angular column {i}");
        }
    }

    #[test]
    fn refuses_what_it_cannot_read() {
        assert!(matches!(
            LegKinematics::from_mjcf("<mujoco"),
            Err(KinematicsError::Xml(_))
        ));
        assert!(matches!(
            LegKinematics::from_mjcf("<mujoco><worldbody/></mujoco>"),
            Err(KinematicsError::MissingBody(_))
        ));
        let euler = TWO_LINK.replace(
            r#"name="left_knee_link" pos"#,
            r#"name="left_knee_link" euler="0 0 1" pos"#,
        );
        assert!(matches!(
            LegKinematics::from_mjcf(&euler),
            Err(KinematicsError::Unsupported(_))
        ));
        let bad = TWO_LINK.replace(
            r#"pos="0 0 -0.4"><joint name="left_knee"#,
            r#"pos="0 x -0.4"><joint name="left_knee"#,
        );
        assert!(matches!(
            LegKinematics::from_mjcf(&bad),
            Err(KinematicsError::BadAttribute { .. })
        ));
        let missing = TWO_LINK.replace("left_hip_yaw_joint", "left_waist_joint");
        assert!(LegKinematics::from_mjcf(&missing).is_err());
    }
}
