//! The `Origin` check of the live view's handshake.
//!
//! A browser names the page that opens a WebSocket in the `Origin` header, and lets any page
//! open one to any address: without this check a page from the lab network or the internet (or
//! one reaching 127.0.0.1 through DNS rebinding) could read the rig's live data from a browser
//! on the rig's machine. Clients that are not browser pages (scripts, most native clients)
//! send no `Origin` and are served.

use std::net::{Ipv4Addr, Ipv6Addr};

/// Whether an `Origin` header value names a page served by this machine: scheme `http` or
/// `https`, host `localhost`, a loopback IPv4 address or `[::1]`, an optional port, and
/// nothing else (an origin has no path, user info or query, so any of those refuses it).
/// `http://localhost.evil.com` names another host and is refused.
pub(crate) fn is_local_origin(origin: &str) -> bool {
    let origin = origin.to_ascii_lowercase();
    let Some(authority) = origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
    else {
        return false;
    };
    let (local_host, port) = match authority.strip_prefix('[') {
        Some(bracketed) => {
            let Some((ip, rest)) = bracketed.split_once(']') else {
                return false;
            };
            (
                ip.parse::<Ipv6Addr>().is_ok_and(|ip| ip.is_loopback()),
                rest,
            )
        }
        None => {
            let (host, rest) = authority.split_at(authority.find(':').unwrap_or(authority.len()));
            let local =
                host == "localhost" || host.parse::<Ipv4Addr>().is_ok_and(|ip| ip.is_loopback());
            (local, rest)
        }
    };
    let port_ok = match port.strip_prefix(':') {
        None => port.is_empty(),
        Some(digits) => {
            !digits.is_empty()
                && digits.bytes().all(|b| b.is_ascii_digit())
                && digits.parse::<u16>().is_ok()
        }
    };
    local_host && port_ok
}

#[cfg(test)]
mod tests {
    use super::is_local_origin;

    #[test]
    fn localhost_origins_pass_and_every_other_origin_is_refused() {
        for ok in [
            "http://localhost",
            "http://localhost:8080",
            "https://localhost:3000",
            "HTTP://LocalHost:8080",
            "http://127.0.0.1",
            "http://127.0.0.1:65535",
            "http://127.1.2.3:80",
            "http://[::1]",
            "https://[::1]:8443",
        ] {
            assert!(is_local_origin(ok), "{ok} refused");
        }
        for bad in [
            "http://evil.example",
            "http://localhost.evil.com",
            "http://localhost.evil.com:8080",
            "http://evil.com#localhost",
            "http://localhost@evil.com",
            "http://evil.com@localhost",
            "http://localhost/",
            "http://localhost:8080/path",
            "http://localhost:",
            "http://localhost:65536",
            "http://localhost:80a",
            "http://localhost:-1",
            "http://127.0.0.1.evil.com",
            "http://128.0.0.1",
            "http://0.0.0.0",
            "http://[::2]",
            "http://[::1",
            "http://[::1]x",
            "http://[::ffff:127.0.0.1]",
            "ws://localhost",
            "file://",
            "null",
            "localhost",
            "",
        ] {
            assert!(!is_local_origin(bad), "{bad} accepted");
        }
    }
}
