//! The person at the rig: steps the MCU cannot do (moving the laser clamp on
//! the light arc, putting a sample or calibration target on the turntable).
//!
//! On the real rig [`ConsoleOperator`] asks on the terminal and waits for
//! Enter; on the simulated rig `SimOperator` (crate `sim-devices`) does it at once.
//! Everything else in a capture is the same for both (DESIGN.md principle 3).

use std::io::{BufRead, Write};

use crate::camera::BoxFuture;
use crate::plan::Pass;

#[derive(Debug, thiserror::Error)]
pub enum OperatorError {
    /// The operator declined (typed `q`) or the terminal closed.
    #[error("the operator cancelled: {0}")]
    Cancelled(String),
    /// The simulated operator could not do it (unknown target, bad angle).
    #[error("{0}")]
    Failed(String),
}

/// Manual steps of a capture or calibration.
pub trait Operator: Send {
    /// Clamp the laser unit at `elevation` (radians above the reference plane).
    fn move_laser_clamp(&mut self, elevation: f64) -> BoxFuture<'_, Result<(), OperatorError>>;
    /// Put `what` on the turntable: the sample (`"sample"`) or a calibration
    /// target (`"checkerboard"`, `"colour-pattern"`, `"white"`, `"two-height"`).
    fn place_on_turntable(&mut self, what: &str) -> BoxFuture<'_, Result<(), OperatorError>>;
    /// The capture's next steps belong to `pass` (at the start, on resume,
    /// and whenever the pass changes): nothing to do at a real rig; the
    /// simulated rig's operator passes it on (pass 1's stripes feed only
    /// band fluxes, and the simulation renders them with fewer photons).
    fn begin_pass(&mut self, pass: Pass) {
        let _ = pass;
    }
}

/// Asks on stderr, waits for Enter on stdin.
#[derive(Debug, Default)]
pub struct ConsoleOperator;

fn ask(prompt: String) -> BoxFuture<'static, Result<(), OperatorError>> {
    Box::pin(async move {
        tokio::task::spawn_blocking(move || {
            let mut err = std::io::stderr();
            let _ = write!(
                err,
                "\n>>> {prompt}\n    press Enter when done (q + Enter to stop): "
            );
            let _ = err.flush();
            let mut line = String::new();
            match std::io::stdin().lock().read_line(&mut line) {
                Ok(0) => Err(OperatorError::Cancelled("stdin closed".into())),
                Ok(_) if line.trim() == "q" => Err(OperatorError::Cancelled(prompt)),
                Ok(_) => Ok(()),
                Err(e) => Err(OperatorError::Cancelled(e.to_string())),
            }
        })
        .await
        .map_err(|e| OperatorError::Failed(e.to_string()))?
    })
}

impl Operator for ConsoleOperator {
    fn move_laser_clamp(&mut self, elevation: f64) -> BoxFuture<'_, Result<(), OperatorError>> {
        ask(format!(
            "Laser off. Clamp the laser unit on the light arc at {:.1} deg elevation.",
            elevation.to_degrees()
        ))
    }
    fn place_on_turntable(&mut self, what: &str) -> BoxFuture<'_, Result<(), OperatorError>> {
        ask(format!(
            "Put the {what} on the turntable, centred, top surface at z = 0."
        ))
    }
}
