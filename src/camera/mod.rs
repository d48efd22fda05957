//! Cameras: the `FrameSource` trait, V4L2 capture and the simulated GelSight camera (being
//! written).
