//! A set of joint indices.

use serde::{Deserialize, Serialize};

/// A set of joints (indices below [`JointMask::CAPACITY`]), e.g. the joints whose torque
/// was clipped in a step. Copy, no allocation; serialises as its bit pattern.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct JointMask(u64);

impl JointMask {
    /// The largest number of joints a mask can describe.
    pub const CAPACITY: usize = 64;

    pub const fn empty() -> Self {
        Self(0)
    }

    /// Adds `joint`; indices at or above [`JointMask::CAPACITY`] are outside any robot the
    /// engine accepts (checked where masks are made) and are ignored.
    pub fn insert(&mut self, joint: usize) {
        if joint < Self::CAPACITY {
            self.0 |= 1 << joint;
        }
    }

    pub fn contains(&self, joint: usize) -> bool {
        joint < Self::CAPACITY && self.0 & (1 << joint) != 0
    }

    pub fn is_empty(&self) -> bool {
        self.0 == 0
    }

    pub fn len(&self) -> usize {
        self.0.count_ones() as usize
    }

    /// The joints in increasing order.
    pub fn iter(&self) -> impl Iterator<Item = usize> + '_ {
        (0..Self::CAPACITY).filter(|&j| self.contains(j))
    }

    pub fn union(self, other: JointMask) -> JointMask {
        JointMask(self.0 | other.0)
    }
}
