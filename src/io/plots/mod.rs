//! Pictures drawn for a person (plotters, with an embedded font): cost surfaces as heat maps and
//! polar views, detected corners over their image.

pub mod overlay;
pub mod plot;
