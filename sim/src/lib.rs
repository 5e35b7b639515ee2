//! The rig without hardware: emulated MCU running the firmware's Controller, virtual serial links, fault injection.
