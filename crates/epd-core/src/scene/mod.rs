//! What lies ahead of the sensor: the survey of a frame near a bend or a tee
//! (`segment`, on the departure profile of `profile`), the torus of a bend with its exact ray cast (`torus`) and the bend's fit
//! (`bend`), and where an opening begins (`edge`).

pub mod bend;
pub mod edge;
pub mod profile;
pub mod segment;
pub mod torus;
