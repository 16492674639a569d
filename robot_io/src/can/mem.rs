//! An in-process CAN: every frame one endpoint sends reaches every other endpoint on that bus, in
//! order, like a real bus. For tests on machines whose kernel has no CAN.
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError, Sender};
use std::time::Duration;

use super::{BusError, CanBuses, CanFrame};

pub struct MemBuses {
    buses: usize,
    rx: Receiver<(usize, CanFrame)>,
    peers: Vec<Sender<(usize, CanFrame)>>,
}

/// `endpoints` nodes sharing `buses` buses.
pub fn mem_buses(buses: usize, endpoints: usize) -> Vec<MemBuses> {
    let (txs, rxs): (Vec<_>, Vec<_>) = (0..endpoints).map(|_| channel()).unzip();
    rxs.into_iter()
        .enumerate()
        .map(|(i, rx)| MemBuses {
            buses,
            rx,
            peers: txs
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, t)| t.clone())
                .collect(),
        })
        .collect()
}

fn gone(bus: usize) -> BusError {
    BusError {
        bus,
        name: "mem".into(),
        io: std::io::Error::new(std::io::ErrorKind::BrokenPipe, "every other node left the bus"),
    }
}

impl CanBuses for MemBuses {
    fn count(&self) -> usize {
        self.buses
    }
    fn send(&mut self, bus: usize, frame: &CanFrame) -> Result<bool, BusError> {
        // A peer that left is like a node powered off: the frame is simply not heard there.
        let heard = self.peers.iter().filter(|p| p.send((bus, *frame)).is_ok()).count();
        if heard == 0 && !self.peers.is_empty() {
            return Err(gone(bus));
        }
        Ok(true)
    }
    fn recv(&mut self, timeout: Duration) -> Result<Option<(usize, CanFrame)>, BusError> {
        match self.rx.recv_timeout(timeout) {
            Ok(f) => Ok(Some(f)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(gone(0)),
        }
    }
}
