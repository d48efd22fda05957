//! A pseudo-terminal for the serial mocks: the mock holds the master, the rig opens the slave
//! path like any serial port.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsRawFd, OwnedFd};
use std::path::PathBuf;

use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::pty::openpty;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use tokio::io::unix::AsyncFd;

/// The master side of a raw pty, non-blocking, driven by tokio.
pub struct PtyMaster {
    fd: AsyncFd<File>,
    /// Kept open so the master never sees a hang-up while the rig reopens the port.
    _slave: OwnedFd,
    path: PathBuf,
}

impl PtyMaster {
    /// Opens a pty in raw mode (no echo, no CR/LF translation). Must be called inside a tokio
    /// runtime.
    pub fn open() -> io::Result<Self> {
        let pty = openpty(None, None).map_err(io::Error::from)?;
        let mut t = tcgetattr(&pty.slave).map_err(io::Error::from)?;
        cfmakeraw(&mut t);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        let path = std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd()))
            .or_else(|_| nix::unistd::ttyname(&pty.slave).map_err(io::Error::from))?;
        let flags = fcntl(pty.master.as_raw_fd(), FcntlArg::F_GETFL).map_err(io::Error::from)?;
        let flags = OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK;
        fcntl(pty.master.as_raw_fd(), FcntlArg::F_SETFL(flags)).map_err(io::Error::from)?;
        // SAFETY: the File owns the master fd for as long as the AsyncFd lives (it is moved in
        // and only dropped with it), so the registered fd stays valid and is not reused.
        let fd = unsafe { AsyncFd::register(File::from(pty.master)) }.map_err(io::Error::from)?;
        Ok(Self {
            fd,
            _slave: pty.slave,
            path,
        })
    }

    /// The slave's path, e.g. `/dev/pts/7`.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Reads what is available (waits until something is).
    pub async fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            let mut guard = self.fd.readable().await?;
            match guard.try_io(|inner| inner.get_ref().read(buf)) {
                Ok(r) => return r,
                Err(_would_block) => continue,
            }
        }
    }

    /// Writes all of `data`.
    pub async fn write_all(&self, mut data: &[u8]) -> io::Result<()> {
        while !data.is_empty() {
            let mut guard = self.fd.writable().await?;
            match guard.try_io(|inner| inner.get_ref().write(data)) {
                Ok(Ok(0)) => return Err(io::ErrorKind::WriteZero.into()),
                Ok(Ok(n)) => data = &data[n..],
                Ok(Err(e)) => return Err(e),
                Err(_would_block) => continue,
            }
        }
        Ok(())
    }
}
