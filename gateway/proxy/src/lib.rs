//! The live pass-through (`gateway proxy`): the operator keeps the G-code sender they
//! use (UGS, CNCjs, bCNC); it connects to a pseudo-terminal the gateway creates, which
//! answers as a GRBL 1.1 controller, while the gateway rewrites every line with the
//! compensation and streams the pieces to the real controller.
//!
//! * [`core`]: the state machine, sans-IO (bytes in, bytes out): answers in order, one
//!   per sender line; character counting towards the controller; real-time bytes
//!   passed at once; status reports turned back into programmed coordinates; a reset or
//!   a restart drops what was pending and resends nothing.
//! * [`serve`]: the I/O loop over the pseudo-terminal and the controller's port.

pub mod core;
pub mod line_rewriter;
pub mod serve;

pub use crate::core::{
    refusal_code, AfterHoming, InUse, LineAccount, Proxy, ProxyStats, ReferenceHook, Rereference,
    MAX_UNANSWERED_LINES, RAW_LINE_KEPT, RX_BUFFER, UNREFERENCED_CODE,
};
pub use line_rewriter::{CartesianRewriter, FiveAxisRewriter, LineRewriter};
pub use serve::{serve, serve_with_camera, Ending, ReferenceFrames, SenderPort};

#[cfg(test)]
mod tests;
