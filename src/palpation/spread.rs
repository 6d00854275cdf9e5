//! How far each landmark moves when the endplate regions' angle bound moves
//! by [`ANGLE_SPREAD_DEG`] either way: the landmarks that hang on a face
//! near the protocol's 40 deg. Scaling a vertebra 15 % more along one axis
//! than another turns a face at 40 deg by up to 8 deg, so a region drawn on
//! the same vertebra at another size, or by another operator reading "about
//! 40 deg", may hold that face or not; where it is the extreme face, the
//! landmark jumps by a face's size and the pedicle cut (a fifth of the
//! depth behind `SP`/`IP`) moves with it. On the scoliosis-dev meshes,
//! a landmark with a spread over 1.5 mm is 2-5 times as likely to be over
//! 3 mm from the maker's as one without.

use super::body::{self, EndplatePoints};
use super::{pedicle, BodyState};
use crate::landmarks::Code;
use nalgebra::Point3;
use std::collections::BTreeMap;

/// The angle bound's move either way (deg).
pub(crate) const ANGLE_SPREAD_DEG: f64 = 8.0;

/// The points that hang on the endplate regions (local coordinates):
/// the endplate landmarks (lateral ones by both rules) and the pedicles.
fn region_points(
    sup: &EndplatePoints,
    inf: &EndplatePoints,
    st: &BodyState,
) -> Vec<(Code, Point3<f64>)> {
    use Code::*;
    let mut out = vec![
        (SEC, sup.centre),
        (SA, sup.front),
        (SP, sup.back),
        (SR, sup.right),
        (SR, sup.furthest_right),
        (SL, sup.left),
        (SL, sup.furthest_left),
        (IEC, inf.centre),
        (IA, inf.front),
        (IP, inf.back),
        (IR, inf.right),
        (IR, inf.furthest_right),
        (IL, inf.left),
        (IL, inf.furthest_left),
    ];
    let x_cut = pedicle::pedicle_cut_x(sup, inf);
    for (side, top, bot) in [(1.0, PTR, PBR), (-1.0, PTL, PBL)] {
        if let Some(p) = pedicle::pedicle_section(&st.lm, x_cut, side) {
            out.push((top, p.top));
            out.push((bot, p.base));
        }
    }
    out
}

/// Per landmark, the largest distance (m) between where it is and where it
/// would be with the endplate regions drawn at 40 -/+ [`ANGLE_SPREAD_DEG`]
/// (each lateral landmark by both the rim-middle and the furthest rule);
/// a bound at which a region vanishes is skipped.
pub(crate) fn region_spread(st: &BodyState) -> BTreeMap<Code, f64> {
    let here = region_points(&st.sup_pts, &st.inf_pts, st);
    let mut spread: BTreeMap<Code, f64> = here.iter().map(|(c, _)| (*c, 0.0)).collect();
    let column = Some(st.walls.column_x());
    for delta in [-ANGLE_SPREAD_DEG, ANGLE_SPREAD_DEG] {
        let angle = body::ENDPLATE_MAX_ANGLE_DEG + delta;
        // The two regions at the moved bound, and their landmarks.
        let pts = |sup: bool| {
            body::find_endplate_within(&st.lm, &st.walls, sup, angle)
                .and_then(|e| body::endplate_points(&st.lm, &e, column))
        };
        let (Some(sup), Some(inf)) = (pts(true), pts(false)) else {
            continue;
        };
        // Each point against its counterpart (same code, same rule).
        let there = region_points(&sup, &inf, st);
        for ((c, a), (c2, b)) in here.iter().zip(&there) {
            if c == c2 {
                let s = spread.entry(*c).or_default();
                *s = s.max((a - b).norm());
            }
        }
    }
    spread
}
