//! The solver's data: [`Workspace`], every scratch buffer a solve of one
//! [`System`] needs (kinematic buffers per scalar type, the dense and the
//! structured statics tangent with their factors, the dynamics buffers),
//! sized once from the system so repeated solves allocate nothing. The
//! algorithms (`kinematics`, `forces`, `statics`, `tree`, `dynamics`) fill
//! and read it; this file depends on none of them.

use super::linalg::{DenseLu, Lu6};
use super::scalar::{Scalar, D6};
use super::system::{BodyIndex, Pose, System, SystemId};
use crate::error::{Error, Result};
use nalgebra::{DMatrix, Matrix3, Matrix6, Vector3, Vector6};
use num_dual::Dual64;

/// Kinematic buffers for one scalar type.
#[derive(Debug, Clone)]
pub struct KinBuf<T: Scalar> {
    /// Free dofs as scalars.
    pub q: Vec<T>,
    /// X_GB per body.
    pub x_gb: Vec<Pose<T>>,
    /// Motion subspace per dof: (angular, linear about the ground origin), ground axes.
    pub h: Vec<[Vector3<T>; 2]>,
    /// Wrench per body: (moment about the ground origin, force), ground axes.
    pub w: Vec<[Vector3<T>; 2]>,
    /// Generalised force per dof.
    pub tau: Vec<T>,
}

impl<T: Scalar> KinBuf<T> {
    /// Buffers sized for `sys`: zero coordinates, identity poses, zero wrenches.
    pub fn new(sys: &System) -> Self {
        let n = sys.n_dofs();
        let nb = sys.n_bodies();
        KinBuf {
            q: vec![T::zero(); n],
            x_gb: vec![Pose::identity(); nb],
            h: vec![[Vector3::zeros(), Vector3::zeros()]; n],
            w: vec![[Vector3::zeros(), Vector3::zeros()]; nb],
            tau: vec![T::zero(); n],
        }
    }
}

/// Which factorisation of the statics tangent is valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Factored {
    None,
    Dense,
    Tree,
}

/// All scratch buffers for a system. Make one per thread and reuse it.
#[derive(Debug, Clone)]
pub struct Workspace {
    pub(crate) k64: KinBuf<f64>,
    pub(crate) kd6: KinBuf<D6>,
    pub(crate) kd1: KinBuf<Dual64>,
    /// Jacobian of the generalised force w.r.t. q (statics tangent), and its LU.
    pub(crate) lu: DenseLu,
    /// Structured (tree) statics tangent and its factors.
    pub(crate) tree: TreeTangent,
    /// Structure id of the system this workspace was made for.
    pub(crate) structure: u64,
    /// Which factorisation (if any) holds the tangent of the last Newton step.
    pub(crate) factored: Factored,
    /// Identity of the system whose tangent `factored` holds (stale when
    /// the system solved with differs).
    pub(crate) factored_for: Option<SystemId>,
    pub(crate) r: Vec<f64>,
    pub(crate) dq: Vec<f64>,
    pub(crate) q_trial: Vec<f64>,
    /// Dynamics: mass matrix (Cholesky in place), velocities and bias.
    pub(crate) mass: DMatrix<f64>,
    pub(crate) vel: Vec<[Vector3<f64>; 2]>,
    pub(crate) acc: Vec<[Vector3<f64>; 2]>,
    pub(crate) hdot: Vec<[Vector3<f64>; 2]>,
    pub(crate) comp: Vec<SpatialInertia>,
    pub(crate) rhs: Vec<f64>,
    /// Coordinate rates of the current speeds (`qdot = N(q) u`).
    pub(crate) qdot: Vec<f64>,
}

impl Workspace {
    /// A workspace sized for `sys`, with no factorised tangent yet.
    pub fn new(sys: &System) -> Self {
        let n = sys.n_dofs();
        let nb = sys.n_bodies();
        Workspace {
            k64: KinBuf::new(sys),
            kd6: KinBuf::new(sys),
            kd1: KinBuf::new(sys),
            lu: DenseLu::new(n),
            tree: TreeTangent::new(sys),
            structure: sys.id.structure,
            factored: Factored::None,
            factored_for: None,
            r: vec![0.0; n],
            dq: vec![0.0; n],
            q_trial: vec![0.0; n],
            mass: DMatrix::zeros(n, n),
            vel: vec![[Vector3::zeros(), Vector3::zeros()]; nb],
            acc: vec![[Vector3::zeros(), Vector3::zeros()]; nb],
            hdot: vec![[Vector3::zeros(), Vector3::zeros()]; n],
            comp: vec![SpatialInertia::zero(); nb],
            rhs: vec![0.0; n],
            qdot: vec![0.0; n],
        }
    }

    /// The factorisation used by the last Newton step of
    /// [`System::solve_static`]: true when it was the structured (tree) one.
    pub fn used_structured_tangent(&self) -> bool {
        self.factored == Factored::Tree
    }
}

/// A rigid body's spatial inertia about the ground origin in ground axes:
/// mass, first moment `h = m c`, rotational inertia about the origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SpatialInertia {
    /// Mass (kg).
    pub m: f64,
    /// First moment of mass about the ground origin, `m c` (kg m, ground axes).
    pub h: Vector3<f64>,
    /// Rotational inertia about the ground origin (kg m^2, ground axes).
    pub i: Matrix3<f64>,
}

impl SpatialInertia {
    /// The zero inertia (no mass).
    pub(crate) fn zero() -> Self {
        SpatialInertia {
            m: 0.0,
            h: Vector3::zeros(),
            i: Matrix3::zeros(),
        }
    }
}

/// Blocks and factors of the structured tangent, one entry per body, plus
/// the scratch of its solves.
#[derive(Debug, Clone)]
pub(crate) struct TreeTangent {
    /// Every force element couples adjacent bodies (structured path usable).
    pub(crate) usable: bool,
    pub(super) colour: Vec<usize>,
    pub(super) n_colours: usize,
    /// Bodies read by some force element (per assembly).
    pub(super) touched: Vec<bool>,
    /// Motion subspace of the body's joint (columns beyond n_b are zero).
    pub(super) h: Vec<Matrix6<f64>>,
    /// Wrench of the body w.r.t. its own twist, its parent's twist; wrench
    /// of the parent w.r.t. this body's twist.
    pub(super) g_self: Vec<Matrix6<f64>>,
    pub(super) g_par: Vec<Matrix6<f64>>,
    pub(super) g_child: Vec<Matrix6<f64>>,
    /// Joint-local terms and `-Fbar(W_b)`.
    pub(super) local: Vec<Matrix6<f64>>,
    pub(super) neg_fbar: Vec<Matrix6<f64>>,
    /// Factors: block LU, `V_b` (dq_b = u_b + V_b dx_p), `P_b H_b`.
    pub(super) lu: Vec<Lu6>,
    pub(super) v: Vec<Matrix6<f64>>,
    pub(super) ph: Vec<Matrix6<f64>>,
    /// Articulated stiffness accumulated from the children.
    pub(super) acc: Vec<Matrix6<f64>>,
    /// The pivot blocks `D_b` of the last factorisation (padded with the
    /// identity beyond the joint's dofs), for the stability test.
    pub(super) pivots: Vec<Matrix6<f64>>,
    /// Solve scratch.
    pub(super) z: Vec<Vector6<f64>>,
    pub(super) u: Vec<Vector6<f64>>,
    pub(super) dx: Vec<Vector6<f64>>,
}

impl TreeTangent {
    pub(crate) fn new(sys: &System) -> Self {
        let nb = sys.bodies.len();
        let (colour, n_colours) = distance2_colouring(sys);
        let z6 = vec![Matrix6::zeros(); nb];
        TreeTangent {
            usable: tree_coupled(sys),
            colour,
            n_colours,
            touched: vec![false; nb],
            h: z6.clone(),
            g_self: z6.clone(),
            g_par: z6.clone(),
            g_child: z6.clone(),
            local: z6.clone(),
            neg_fbar: z6.clone(),
            lu: vec![Lu6::identity(); nb],
            v: z6.clone(),
            ph: z6.clone(),
            acc: z6.clone(),
            pivots: z6,
            z: vec![Vector6::zeros(); nb],
            u: vec![Vector6::zeros(); nb],
            dx: vec![Vector6::zeros(); nb],
        }
    }
}

/// True when every force element of `sys` couples at most a body and its
/// parent (or ground): the condition for the structured tangent. Loads
/// always are (follower pairs sit on a joint's parent and child).
pub(super) fn tree_coupled(sys: &System) -> bool {
    let adjacent = |a: BodyIndex, b: BodyIndex| {
        a == b
            || sys.bodies.get(a.0).and_then(|x| x.parent) == Some(b)
            || sys.bodies.get(b.0).and_then(|x| x.parent) == Some(a)
    };
    sys.bushings.iter().all(|b| {
        b.fast.is_some()
            || match (b.body1, b.body2) {
                (Some(x), Some(y)) => adjacent(x, y),
                _ => true,
            }
    })
}

/// Greedy distance-2 colouring of the body tree (parents before children):
/// a body's colour differs from its parent's, its grandparent's and its
/// earlier siblings'. Returns (colours, number of colours).
pub(super) fn distance2_colouring(sys: &System) -> (Vec<usize>, usize) {
    let nb = sys.bodies.len();
    let mut colour = vec![0usize; nb];
    // colours already used by the children of each body (+ one for ground)
    let mut used_by_children: Vec<Vec<usize>> = vec![Vec::new(); nb + 1];
    let mut n_colours = 0;
    for bi in 0..nb {
        let parent = sys.bodies[bi].parent.map(|p| p.0);
        let mut forbidden: Vec<usize> = Vec::new();
        if let Some(p) = parent {
            forbidden.push(colour[p]);
            if let Some(gp) = sys.bodies[p].parent {
                forbidden.push(colour[gp.0]);
            }
            forbidden.extend_from_slice(&used_by_children[p]);
        }
        let c = (0..).find(|c| !forbidden.contains(c)).unwrap_or(0);
        colour[bi] = c;
        n_colours = n_colours.max(c + 1);
        if let Some(p) = parent {
            used_by_children[p].push(c);
        } else {
            used_by_children[nb].push(c);
        }
    }
    (colour, n_colours)
}

impl System {
    /// Refuse a workspace made for a system of another structure.
    pub(crate) fn check_workspace(&self, ws: &Workspace) -> Result<()> {
        if ws.structure != self.id().structure {
            return Err(Error::invalid(
                "solver",
                "the workspace was made for another system (make one with Workspace::new for this system)",
            ));
        }
        Ok(())
    }
}
