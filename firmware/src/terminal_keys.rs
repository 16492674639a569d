//! Key presses from the terminal `g1fw run --keyboard` runs in, for
//! [`control::keyboard::KeyboardOperator`]: a reader thread off the control path, one byte per key,
//! over a bounded channel (a full channel drops the key: the tick never waits for the terminal).
//! On a terminal, line buffering and echo go off for the run (Ctrl-C still stops it) and come back
//! when the [`TerminalKeys`] guard drops, whatever ended the run.
use std::io::Read;
use std::sync::mpsc::{sync_channel, Receiver};

/// Keys buffered between two ticks at most.
const KEY_BUFFER: usize = 64;

/// Restores the terminal's settings on drop.
pub struct TerminalKeys {
    saved: Option<libc::termios>,
}

/// Starts reading keys from stdin: the receiver for the operator, and the guard that puts the
/// terminal back. Not a terminal (a pipe): its bytes are the keys, read as they come.
pub fn start() -> std::io::Result<(Receiver<u8>, TerminalKeys)> {
    let saved = key_at_a_time()?;
    let (tx, rx) = sync_channel(KEY_BUFFER);
    std::thread::Builder::new().name("g1fw-keys".into()).spawn(move || {
        let mut stdin = std::io::stdin().lock();
        let mut byte = [0u8; 1];
        // Ends at end of input or when the run is over (the receiver dropped).
        while let Ok(1) = stdin.read(&mut byte) {
            if let Err(std::sync::mpsc::TrySendError::Disconnected(_)) = tx.try_send(byte[0]) {
                break;
            }
        }
    })?;
    Ok((rx, TerminalKeys { saved }))
}

/// On a terminal: keys without Enter and without echo (signals kept). Returns the settings to
/// restore, or `None` when stdin is not a terminal.
fn key_at_a_time() -> std::io::Result<Option<libc::termios>> {
    // SAFETY: isatty takes a descriptor number only.
    if unsafe { libc::isatty(libc::STDIN_FILENO) } != 1 {
        return Ok(None);
    }
    // SAFETY: termios is plain data (zeroed is a valid value); tcgetattr writes into the one we
    // own and pass a valid pointer to.
    let mut saved: libc::termios = unsafe { std::mem::zeroed() };
    // SAFETY: as above.
    if unsafe { libc::tcgetattr(libc::STDIN_FILENO, &mut saved) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    let mut raw = saved;
    raw.c_lflag &= !(libc::ICANON | libc::ECHO);
    raw.c_cc[libc::VMIN] = 1;
    raw.c_cc[libc::VTIME] = 0;
    // SAFETY: a valid, initialised termios that outlives the call.
    if unsafe { libc::tcsetattr(libc::STDIN_FILENO, libc::TCSANOW, &raw) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(Some(saved))
}

impl Drop for TerminalKeys {
    fn drop(&mut self) {
        if let Some(saved) = self.saved {
            // SAFETY: the settings read at start, valid and initialised.
            unsafe { libc::tcsetattr(libc::STDIN_FILENO, libc::TCSANOW, &saved) };
        }
    }
}
