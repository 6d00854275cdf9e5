//! The real scalars the generic numerical code (OpenSim functions, the
//! solver's kinematics and forces) is written over: `f64` for plain
//! evaluation, and forward-mode dual numbers (num-dual) for exact
//! derivatives: [`Dual64`] (one direction) and [`D6`] (six directions at once).

use nalgebra::RealField;
use num_dual::{Dual64, DualSVec64};

/// A real scalar usable by the generic code. `re` is the value part.
pub trait Scalar: RealField + Copy {
    /// The value (real) part.
    fn re(&self) -> f64;
    /// A constant.
    fn c(x: f64) -> Self;
}

impl Scalar for f64 {
    #[inline]
    fn re(&self) -> f64 {
        *self
    }
    #[inline]
    fn c(x: f64) -> Self {
        x
    }
}

/// Six-direction dual number.
pub type D6 = DualSVec64<6>;

/// The dual numbers: value part `re`, constants without derivative part.
macro_rules! dual_scalar {
    ($($t:ty),*) => {$(
        impl Scalar for $t {
            #[inline]
            fn re(&self) -> f64 {
                self.re
            }
            #[inline]
            fn c(x: f64) -> Self {
                <$t>::from_re(x)
            }
        }
    )*};
}
dual_scalar!(Dual64, D6);
