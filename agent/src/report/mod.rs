//! What a run leaves for people to read: its run files (`metrics`), TensorBoard event
//! files, figures (`plot`), videos, Pareto-front measures (`pareto`) and fronts
//! (`front`). Imports the core and the env boundary, never the runtime above it.

pub(crate) mod font;
pub mod front;
pub mod metrics;
pub mod pareto;
pub mod plot;
pub mod tensorboard;
pub mod video;
