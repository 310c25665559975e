//! The transports: [`http`] (axum, with the WebSocket in [`ws`] and the
//! studio's assets in [`studio`]) and [`grpc`] (tonic). They only convert
//! wire types to the requests of [`crate::service`] and back
//! (ARCHITECTURE rule 1); the use cases, permits, defaults and errors live
//! there.

pub mod grpc;
pub mod http;
pub mod studio;
pub mod ws;
