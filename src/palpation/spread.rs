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
use super::{pedicle, BodyState, PalpatedLandmark};
use crate::landmarks::Code;
use nalgebra::Point3;
use std::collections::BTreeMap;

/// The angle bound's move either way (deg).
pub(crate) const ANGLE_SPREAD_DEG: f64 = 8.0;

/// The endplate landmarks of two endplates (local coordinates), the
/// lateral ones by both rules.
fn endplate_points(sup: &EndplatePoints, inf: &EndplatePoints) -> Vec<(Code, Point3<f64>)> {
    use Code::*;
    vec![
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
    ]
}

/// The pedicle codes, in the order [`pedicle_points`] gives them.
const PEDICLES: [(f64, Code, Code); 2] =
    [(1.0, Code::PTR, Code::PBR), (-1.0, Code::PTL, Code::PBL)];

/// The pedicle landmarks of the cut the two endplates place.
fn pedicle_points(
    st: &BodyState,
    sup: &EndplatePoints,
    inf: &EndplatePoints,
) -> Vec<(Code, Point3<f64>)> {
    let x_cut = pedicle::pedicle_cut_x(sup, inf);
    PEDICLES
        .iter()
        .filter_map(|&(side, top, bot)| {
            pedicle::pedicle_section(&st.lm, x_cut, side).map(|p| [(top, p.top), (bot, p.base)])
        })
        .flatten()
        .collect()
}

/// Per landmark, the largest distance (m) between where it is and where it
/// would be with the endplate regions drawn at 40 -/+ [`ANGLE_SPREAD_DEG`]
/// (each lateral landmark by both the rim-middle and the furthest rule);
/// a bound at which a region vanishes is skipped.
///
/// `placed`: the landmarks as placed (local coordinates), whose pedicle
/// points are not cut again.
pub(crate) fn region_spread(
    st: &BodyState,
    placed: &BTreeMap<Code, PalpatedLandmark>,
) -> BTreeMap<Code, f64> {
    let mut here = endplate_points(&st.sup_pts, &st.inf_pts);
    here.extend(
        PEDICLES
            .iter()
            .flat_map(|&(_, top, bot)| [top, bot])
            .filter_map(|c| placed.get(&c).map(|l| (c, l.point))),
    );
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
        // Each point against its counterpart at the moved bound.
        let mut there = endplate_points(&sup, &inf);
        there.extend(pedicle_points(st, &sup, &inf));
        for code in spread.keys().copied().collect::<Vec<_>>() {
            let of = |v: &[(Code, Point3<f64>)]| -> Vec<Point3<f64>> {
                v.iter()
                    .filter(|(c, _)| *c == code)
                    .map(|(_, p)| *p)
                    .collect()
            };
            // The k-th point of a code is the same rule's at both bounds.
            let moved = of(&here)
                .iter()
                .zip(&of(&there))
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
            if let Some(s) = spread.get_mut(&code) {
                *s = s.max(moved);
            }
        }
    }
    spread
}
