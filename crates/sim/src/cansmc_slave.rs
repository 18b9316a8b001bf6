//! Simulated CANsmc servo slave.
