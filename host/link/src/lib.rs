//! Async host link client to the rig MCU: typed calls, retransmission, heartbeat, reset recovery.
