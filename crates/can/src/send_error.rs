//! Why frames were not sent: the errors every backend and the bus task
//! share (the backends below the bus task name these, never the task).

/// Why a frame was not accepted for transmission.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SendError {
    /// The controller is bus-off.
    #[error("bus {0} is bus-off")]
    BusOff(String),
    /// The interface is down.
    #[error("bus {0} is down")]
    Down(String),
    /// A CAN FD frame on a bus that is not configured for CAN FD.
    #[error("bus {0} is not configured for CAN FD")]
    FdNotSupported(String),
    /// Too many client frames already wait for the bus's client share
    /// (see [`crate::budget`]).
    #[error(
        "bus {bus}: {queued} frames already wait for the client share of the bus ({percent} %); send more slowly, or raise the bus's client_share_percent"
    )]
    BudgetExhausted {
        /// Bus name.
        bus: String,
        /// Client and bulk frames waiting when this batch came.
        queued: u64,
        /// The client share in percent.
        percent: u8,
    },
    /// The operating system refused the frame.
    #[error("bus {bus}: {message}")]
    Io {
        /// Bus name.
        bus: String,
        /// What went wrong.
        message: String,
    },
}

/// A frame batch could not be sent completely.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{error} ({sent} of {total} frames sent)")]
pub struct SendFailure {
    /// Frames of the batch that were sent before the failure.
    pub sent: usize,
    /// Frames in the batch.
    pub total: usize,
    /// Why sending stopped.
    pub error: SendError,
}
