//! CANsmc slave protocol state machine (sans-IO).
