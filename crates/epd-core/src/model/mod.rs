//! The model: β and the SCS → PCS transform (eq. 3), the residuals of the three methods
//! with their analytic gradients, and the symmetries under which a cloud fits equally well.

pub mod params;
pub mod residual;
pub mod symmetry;
