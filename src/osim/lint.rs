//! What is legal but suspicious in a whole model (the rules are in
//! `physics`): named warnings that `info` and `simulate` print.

use super::model::{Force, Model};
use super::physics::{breaks_triangle, principal_moments};

/// Named warnings about what is legal but suspicious in `model`.
pub fn warnings(model: &Model) -> Vec<String> {
    let mut out = Vec::new();
    // Inertia that no mass distribution has.
    for b in &model.bodies {
        if breaks_triangle(&b.inertia) {
            let m = principal_moments(&b.inertia);
            out.push(format!(
                "body '{}': principal moments {:.4e} {:.4e} {:.4e} break the triangle inequality (I1 + I2 >= I3); simulate --dynamic refuses it",
                b.name, m[0], m[1], m[2]
            ));
        }
    }
    // Defaults outside their range.
    for c in model.coordinates() {
        if c.default_value < c.range[0] || c.default_value > c.range[1] {
            out.push(format!(
                "coordinate '{}': default_value {} is outside its range [{}, {}]",
                c.name, c.default_value, c.range[0], c.range[1]
            ));
        }
    }
    // Negative stiffness: the equilibrium may be unstable.
    for f in &model.forces {
        if let Force::Bushing(b) = f {
            let k = b
                .rotational_stiffness
                .iter()
                .chain(b.translational_stiffness.iter());
            if k.clone().any(|&x| x < 0.0) {
                out.push(format!(
                    "bushing '{}': negative stiffness ({} / {}): the equilibrium may be unstable",
                    b.name,
                    fmt3(&b.rotational_stiffness),
                    fmt3(&b.translational_stiffness)
                ));
            }
        }
    }
    out
}

fn fmt3(v: &nalgebra::Vector3<f64>) -> String {
    format!("{} {} {}", v[0], v[1], v[2])
}
