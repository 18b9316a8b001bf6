//! CANsmc master protocol state machine (sans-IO): phases P0, P1, P2.
