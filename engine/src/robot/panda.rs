//! The Franka Emika Panda: modified-DH kinematics (Franka's published parameters),
//! dynamics identified by C. Gaz, M. Cognetti, A. Oliva, P. Robuffo Giordano, A. De Luca,
//! "Dynamic identification of the Franka Emika Panda robot with retrieval of feasible
//! parameters using penalty-based optimization", IEEE RA-L 2019, and the hand as a fixed
//! body on the flange.
//!
//! The joints carry their motors' reflected rotor inertia ([`PANDA_ARMATURE`], the
//! model's armature), which the link-side identification does not include. It matters
//! under external forces: without it the wrist's joint-space inertia is a few 0.01 kg·m²,
//! so a push on the hand mostly spins the wrist; with it the same push mostly translates
//! the arm, as on the real robot. Franka's joint-torque loop hides part of the rotor
//! inertia from the commanded torque, so the full reflected value is the upper end of what
//! a push meets.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
use std::sync::OnceLock;

use super::{JointLimits, SerialChain};
use crate::math::{DVector, Matrix3, Real, Vector3};
use crate::model::{Frame, Model, ModelError, ModifiedDh};
use crate::spatial::{Inertia, Se3};

/// The shipped URDF (`engine/assets/panda.urdf`), generated from the tables of this module
/// by `engine/assets/generate_panda_urdf.py`.
pub const PANDA_URDF: &str = include_str!("../../assets/panda.urdf");

/// The "home" posture `[0, −π/4, 0, −3π/4, 0, π/2, π/4]`.
pub const PANDA_HOME: [Real; 7] = [
    0.0,
    -FRAC_PI_4,
    0.0,
    -3.0 * FRAC_PI_4,
    0.0,
    FRAC_PI_2,
    FRAC_PI_4,
];

/// Modified DH `(a_{i−1}, dᵢ, α_{i−1})` of joints 1–7, then the flange.
const DH: [ModifiedDh; 8] = [
    ModifiedDh::new(0.0, 0.333, 0.0),
    ModifiedDh::new(0.0, 0.0, -FRAC_PI_2),
    ModifiedDh::new(0.0, 0.316, FRAC_PI_2),
    ModifiedDh::new(0.0825, 0.0, FRAC_PI_2),
    ModifiedDh::new(-0.0825, 0.384, -FRAC_PI_2),
    ModifiedDh::new(0.0, 0.0, FRAC_PI_2),
    ModifiedDh::new(0.088, 0.0, FRAC_PI_2),
    ModifiedDh::new(0.0, 0.107, 0.0),
];

/// Mass, centre of mass and `(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)` about it, link frame.
struct LinkInertia {
    mass: Real,
    com: [Real; 3],
    inertia: [Real; 6],
}

impl LinkInertia {
    fn spatial(&self) -> Inertia {
        let [xx, yy, zz, xy, xz, yz] = self.inertia;
        Inertia::from_com(
            self.mass,
            Vector3::from(self.com),
            Matrix3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz),
        )
    }
}

const LINKS: [LinkInertia; 7] = [
    LinkInertia {
        mass: 4.970684,
        com: [0.003875, 0.002081, -0.04762],
        inertia: [0.70337, 0.70661, 0.009117, -0.000139, 0.006772, 0.019169],
    },
    LinkInertia {
        mass: 0.646926,
        com: [-0.003141, -0.02872, 0.003495],
        inertia: [0.007962, 0.02811, 0.025995, -0.003925, 0.010254, 0.000704],
    },
    LinkInertia {
        mass: 3.228604,
        com: [0.027518, 0.039252, -0.066502],
        inertia: [0.037242, 0.036155, 0.01083, -0.004761, -0.011396, -0.012805],
    },
    LinkInertia {
        mass: 3.587895,
        com: [-0.05317, 0.104419, 0.027454],
        inertia: [0.025853, 0.019552, 0.028323, 0.007796, -0.001332, 0.008641],
    },
    LinkInertia {
        mass: 1.225946,
        com: [-0.011953, 0.041065, -0.038437],
        inertia: [0.035549, 0.029474, 0.008627, -0.002117, -0.004037, 0.000229],
    },
    LinkInertia {
        mass: 1.666555,
        com: [0.060149, -0.014117, -0.010517],
        inertia: [0.001964, 0.004354, 0.005433, 0.000109, -0.001158, 0.000341],
    },
    LinkInertia {
        mass: 0.735522,
        com: [0.010517, -0.004252, 0.061597],
        inertia: [
            0.012516, 0.010027, 0.004815, -0.000428, -0.001196, -0.000741,
        ],
    },
];

/// The hand, mounted at the flange rotated by `−π/4` about `z`.
const HAND: LinkInertia = LinkInertia {
    mass: 0.73,
    com: [-0.01, 0.0, 0.03],
    inertia: [0.001, 0.0025, 0.0017, 0.0, 0.0, 0.0],
};
const HAND_YAW: Real = -FRAC_PI_4;

const Q_MIN: [Real; 7] = [
    -2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973,
];
const Q_MAX: [Real; 7] = [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973];
const QD_MAX: [Real; 7] = [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61];
const QDD_MAX: [Real; 7] = [15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0];
const TAU_MAX: [Real; 7] = [87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0];
const TAU_RATE_MAX: Real = 1000.0;
/// Reflected rotor inertia of each joint, kg·m²: Franka's figures for its FR3 drives
/// (the Panda's successor, same drive sizes: 87 N·m joints 1–4, 12 N·m joints 5–7), as
/// used by Drake's `franka_description` (`rotor_inertia · gear_ratio²`).
pub const PANDA_ARMATURE: [Real; 7] = [
    0.605721456,
    0.605721456,
    0.462474144,
    0.462474144,
    0.205544064,
    0.205544064,
    0.205544064,
];

/// Franka's published joint limits, including `q̈` and the 1000 N·m/s torque rate.
pub fn panda_limits() -> JointLimits {
    JointLimits {
        q_min: DVector::from_row_slice(&Q_MIN),
        q_max: DVector::from_row_slice(&Q_MAX),
        qd_max: DVector::from_row_slice(&QD_MAX),
        qdd_max: DVector::from_row_slice(&QDD_MAX),
        tau_max: DVector::from_row_slice(&TAU_MAX),
        tau_rate_max: DVector::from_element(7, TAU_RATE_MAX),
    }
}

/// The Panda from the shipped URDF, with [`panda_limits`], [`PANDA_ARMATURE`] and the hand
/// as tool frame.
///
/// The URDF is parsed once per process; every call returns a clone sharing that model.
pub fn panda() -> SerialChain {
    static PANDA: OnceLock<SerialChain> = OnceLock::new();
    PANDA
        .get_or_init(|| {
            let mut robot = SerialChain::from_urdf_str(PANDA_URDF)
                .expect("the shipped Panda URDF is valid (tested)");
            robot
                .set_limits(panda_limits())
                .expect("the Panda limits are valid (tested)");
            robot
                .set_armature(DVector::from_row_slice(&PANDA_ARMATURE))
                .expect("the Panda armature is valid (tested)");
            robot
        })
        .clone()
}

/// The same Panda built directly from the modified-DH table and the inertia tables (the
/// source the URDF is generated from).
pub fn panda_from_dh() -> Result<SerialChain, ModelError> {
    let flange = DH[7].placement();
    let hand = flange * Se3::from_rotation(Se3::rotation_about(&Vector3::z(), HAND_YAW));
    let names: Vec<String> = (1..=7).map(|i| format!("panda_link{i}")).collect();
    let mut links: Vec<(&str, ModifiedDh, Inertia)> = names
        .iter()
        .zip(DH.iter().zip(&LINKS))
        .map(|(name, (dh, link))| (name.as_str(), *dh, link.spatial()))
        .collect();
    links[6].2 += hand.act_inertia(&HAND.spatial());
    let frames = vec![
        Frame {
            name: "panda_link8".into(),
            body: Some(6),
            placement: flange,
        },
        Frame {
            name: "panda_hand".into(),
            body: Some(6),
            placement: hand,
        },
    ];
    let mut robot = SerialChain::new(Model::from_modified_dh(
        "panda",
        "panda_link0",
        &links,
        frames,
    )?);
    robot.set_limits(panda_limits())?;
    robot.set_armature(DVector::from_row_slice(&PANDA_ARMATURE))?;
    Ok(robot)
}
