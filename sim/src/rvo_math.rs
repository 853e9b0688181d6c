//! RVO2's float32 vector arithmetic (`Vector2.cc`: products, determinant, division as
//! multiplication by the reciprocal, normalisation) and its `Line`, shared by the agent half of
//! ORCA ([`crate::orca`]) and the obstacle half ([`crate::obstacles`]).

use crate::geom::Vec2f;

pub(crate) const RVO_EPSILON: f32 = 0.00001;

#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Line {
    pub(crate) point: Vec2f,
    pub(crate) direction: Vec2f,
}

#[inline]
pub(crate) fn det(a: Vec2f, b: Vec2f) -> f32 {
    a.x * b.y - a.y * b.x
}

#[inline]
pub(crate) fn dot(a: Vec2f, b: Vec2f) -> f32 {
    a.x * b.x + a.y * b.y
}

#[inline]
pub(crate) fn abs_sq(a: Vec2f) -> f32 {
    dot(a, a)
}

/// RVO2's `Vector2::operator/`: multiply by the reciprocal.
#[inline]
pub(crate) fn div(a: Vec2f, s: f32) -> Vec2f {
    let inv = 1.0f32 / s;
    Vec2f::new(a.x * inv, a.y * inv)
}

#[inline]
pub(crate) fn normalize(a: Vec2f) -> Vec2f {
    div(a, abs_sq(a).sqrt())
}
