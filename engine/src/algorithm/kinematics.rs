//! Forward kinematics.

use super::{DynamicsError, check_vector};
use crate::math::{Real, sin_cos_slice};
use crate::model::{Data, Model};
use crate::spatial::Se3;

/// Places every body: `ᵖMᵢ(qᵢ)` ([`Joint::transform`](crate::model::Joint::transform)) into `data.li_m_i` and
/// `⁰Mᵢ = ⁰Mₚ ᵖMᵢ` into `data.o_m_i`.
pub fn forward_kinematics(model: &Model, data: &mut Data, q: &[Real]) -> Result<(), DynamicsError> {
    check_vector("q", q, model.nv())?;
    place_joints(model, data, q);
    place_bodies(data);
    Ok(())
}

/// `ᵖMᵢ(qᵢ)` of every joint into `data.li_m_i`, the first step of every algorithm; the
/// sines and cosines of all joint angles are taken together ([`sin_cos_slice`]). `q` is
/// already checked.
#[inline(always)]
pub(crate) fn place_joints(model: &Model, data: &mut Data, q: &[Real]) {
    sin_cos_slice(q, &mut data.sin_q, &mut data.cos_q);
    for (i, body) in model.bodies().iter().enumerate() {
        data.li_m_i[i] = body
            .joint
            .transform_from(q[i], data.sin_q[i], data.cos_q[i]);
    }
}

/// `⁰Mᵢ = ⁰Mₚ ᵖMᵢ` of every body into `data.o_m_i`, from the joints' placements in
/// `data.li_m_i` ([`place_joints`]).
#[inline(always)]
pub(crate) fn place_bodies(data: &mut Data) {
    let mut o_m_i = Se3::identity();
    for (li_m_i, o_m) in data.li_m_i.iter().zip(&mut data.o_m_i) {
        o_m_i = o_m_i * *li_m_i;
        *o_m = o_m_i;
    }
}

/// The placement `⁰M_f(q)` of frame `frame` in the base frame, walking the chain only up
/// to the frame's body (no workspace needed).
pub fn frame_placement(model: &Model, q: &[Real], frame: usize) -> Result<Se3, DynamicsError> {
    check_vector("q", q, model.nv())?;
    let frames = model.frames();
    let frame = frames.get(frame).ok_or(DynamicsError::NoSuchFrame {
        index: frame,
        count: frames.len(),
    })?;
    Ok(body_placement(model, q, frame.body) * frame.placement)
}

/// `⁰M_b(q)` of body `body` (`None`: the base); `q` already checked.
pub(crate) fn body_placement(model: &Model, q: &[Real], body: Option<usize>) -> Se3 {
    let count = body.map_or(0, |b| b + 1);
    model.bodies()[..count]
        .iter()
        .zip(q)
        .fold(Se3::identity(), |o_m, (body, &qi)| {
            o_m * body.joint.transform(qi)
        })
}
