//! Software triggers on the MCU's trigger-fired events, for cameras that
//! cannot see the rig's trigger lines (a USB3 camera without trigger wiring,
//! Aravis's fake GigE camera): the MCU still times every exposure and reports
//! each rise of its lines (`Event::TriggerFired`); the relay fires the
//! software trigger of every such camera whose line was in the mask.
//!
//! The frame then starts after the line's rise plus the link's and the
//! camera's latency (milliseconds), so a sweep's dwell must cover that; the
//! capture plans' dwells (the frame period plus a margin) do.

use protocol::Event;
use qhm_link::{Link, LinkError, LinkEvent};

/// Fires one camera's software trigger; `at_us` is when the MCU's line rose.
pub trait SoftwareTrigger: Send + Sync {
    fn fire(&self, at_us: u64);
}

/// Relays the link's trigger-fired events to the software-triggered cameras
/// (arc position, trigger) until the link is dropped. Call it before the first
/// trigger: events before the subscription are not seen.
pub fn relay_triggers(link: &Link, cameras: Vec<(u8, Box<dyn SoftwareTrigger>)>) {
    if cameras.is_empty() {
        return;
    }
    let mut events = link.subscribe();
    tokio::spawn(async move {
        loop {
            match events.recv().await {
                Ok(LinkEvent::Mcu {
                    event: Event::TriggerFired { mask, at_us, .. },
                    ..
                }) => {
                    for (index, trigger) in &cameras {
                        if mask & (1u8 << index) != 0 {
                            trigger.fire(at_us);
                        }
                    }
                }
                Ok(LinkEvent::EventsMissed { count, .. }) => tracing::warn!(
                    "{count} MCU events were lost: software-triggered cameras may miss frames"
                ),
                Err(LinkError::Lagged(n)) => tracing::warn!(
                    "the software-trigger relay fell {n} events behind: cameras may miss frames"
                ),
                Ok(_) => {}
                Err(_) => return,
            }
        }
    });
}
