//! Named frames attached to bodies (links, flange, tool).

use crate::spatial::Se3;

/// A named frame rigidly attached to body `body` (`None`: the fixed base) at `placement`
/// in that body's frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub name: String,
    pub body: Option<usize>,
    pub placement: Se3,
}
