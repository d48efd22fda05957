//! The `Origin` check of the live view's handshake.
//!
//! A browser names the page that opens a WebSocket in the `Origin` header, and lets any page
//! open one to any address: without this check a page from the lab network or the internet (or
//! one reaching 127.0.0.1 through DNS rebinding) could read the rig's live data from a browser
//! on the rig's machine. Clients that are not browser pages (scripts, most native clients)
//! send no `Origin` and are served. A hosted app the operator trusts (Foxglove's web app) is
//! admitted by name ([`AllowedOrigin`], `--live-allow-origin`).

use std::net::{Ipv4Addr, Ipv6Addr};

/// The host of an origin.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Host {
    /// A DNS name, lower case: labels of letters, digits and `-`.
    Name(String),
    V4(Ipv4Addr),
    V6(Ipv6Addr),
}

/// An origin taken apart: scheme (`http` or `https`), host and port.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Parts {
    https: bool,
    host: Host,
    port: Option<u16>,
}

impl Parts {
    /// `scheme://host[:port]`, lower case, without the scheme's default port (a browser
    /// leaves it out of the `Origin` it sends).
    fn normalized(&self) -> String {
        let scheme = if self.https { "https" } else { "http" };
        let host = match &self.host {
            Host::Name(n) => n.clone(),
            Host::V4(ip) => ip.to_string(),
            Host::V6(ip) => format!("[{ip}]"),
        };
        let default = if self.https { 443 } else { 80 };
        match self.port {
            Some(p) if p != default => format!("{scheme}://{host}:{p}"),
            _ => format!("{scheme}://{host}"),
        }
    }
}

/// A DNS name as an origin may hold it: dot-separated labels of ASCII letters, digits and
/// `-` (not at either end of a label), at most 253 characters.
fn is_dns_name(host: &str) -> bool {
    !host.is_empty()
        && host.len() <= 253
        && host.split('.').all(|label| {
            !label.is_empty()
                && label.len() <= 63
                && !label.starts_with('-')
                && !label.ends_with('-')
                && label
                    .bytes()
                    .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-')
        })
}

/// Takes an `Origin` value apart: `http` or `https`, a host, an optional port, and nothing
/// else (an origin has no path, user info, query or fragment, so any of those refuses it).
fn parse(origin: &str) -> Option<Parts> {
    let origin = origin.to_ascii_lowercase();
    let (https, authority) = match origin.strip_prefix("http://") {
        Some(a) => (false, a),
        None => (true, origin.strip_prefix("https://")?),
    };
    let (host, rest) = match authority.strip_prefix('[') {
        Some(bracketed) => {
            let (ip, rest) = bracketed.split_once(']')?;
            (Host::V6(ip.parse::<Ipv6Addr>().ok()?), rest)
        }
        None => {
            let (host, rest) = authority.split_at(authority.find(':').unwrap_or(authority.len()));
            let host = match host.parse::<Ipv4Addr>() {
                Ok(ip) => Host::V4(ip),
                Err(_) if is_dns_name(host) => Host::Name(host.to_owned()),
                Err(_) => return None,
            };
            (host, rest)
        }
    };
    let port = match rest.strip_prefix(':') {
        None if rest.is_empty() => None,
        None => return None,
        Some(digits) => {
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                return None;
            }
            Some(digits.parse::<u16>().ok()?)
        }
    };
    Some(Parts { https, host, port })
}

/// Whether an `Origin` header value names a page served by this machine: scheme `http` or
/// `https`, host `localhost`, a loopback IPv4 address or `[::1]`, an optional port, and
/// nothing else. `http://localhost.evil.com` names another host and is refused.
pub(crate) fn is_local_origin(origin: &str) -> bool {
    parse(origin).is_some_and(|p| match p.host {
        Host::Name(n) => n == "localhost",
        Host::V4(ip) => ip.is_loopback(),
        Host::V6(ip) => ip.is_loopback(),
    })
}

/// An origin admitted besides this machine's pages (`--live-allow-origin`), e.g. the
/// Foxglove web app's `https://app.foxglove.dev`. Held normalized (lower case, without the
/// scheme's default port), and compared whole with the normalized `Origin` of a handshake:
/// no wildcards, no prefixes, so `https://app.foxglove.dev.evil.com` is another origin.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AllowedOrigin(String);

impl AllowedOrigin {
    /// The origin as compared (normalized).
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// Whether the `Origin` header value `origin` is this one.
    pub(crate) fn admits(&self, origin: &str) -> bool {
        parse(origin).is_some_and(|p| p.normalized() == self.0)
    }
}

impl std::fmt::Display for AllowedOrigin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::str::FromStr for AllowedOrigin {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let usage = "an origin is SCHEME://HOST[:PORT] with SCHEME http or https, as a browser \
                     sends it: no path, no trailing slash, no wildcard (e.g. \
                     https://app.foxglove.dev)";
        let t = s.trim();
        if let Some(p) = parse(t) {
            return Ok(AllowedOrigin(p.normalized()));
        }
        // The likely slips, each with its fix.
        let hint = if t.contains('*') {
            " (wildcards are not accepted: name each origin)".to_owned()
        } else if let Some(base) = t.strip_suffix('/').filter(|b| parse(b).is_some()) {
            format!(" (did you mean {base}?)")
        } else if !t.contains("://") && parse(&format!("https://{t}")).is_some() {
            format!(" (did you mean https://{t}?)")
        } else {
            String::new()
        };
        Err(format!("{s:?} is not an origin{hint}: {usage}"))
    }
}

#[cfg(test)]
mod tests {
    use super::{AllowedOrigin, is_local_origin};

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

    #[test]
    fn an_allowed_origin_is_normalized_and_admits_only_itself() {
        let app: AllowedOrigin = "HTTPS://App.Foxglove.dev:443".parse().unwrap();
        assert_eq!(app.as_str(), "https://app.foxglove.dev");
        for same in [
            "https://app.foxglove.dev",
            "https://APP.foxglove.DEV",
            "https://app.foxglove.dev:443",
        ] {
            assert!(app.admits(same), "{same} refused");
        }
        for other in [
            "http://app.foxglove.dev",
            "https://app.foxglove.dev:8443",
            "https://app.foxglove.dev.evil.com",
            "https://evil.com#app.foxglove.dev",
            "https://x.app.foxglove.dev",
            "https://app.foxglove.dev/",
            "https://app.foxglove.dev@evil.com",
            "null",
        ] {
            assert!(!app.admits(other), "{other} admitted");
        }
        let local: AllowedOrigin = "http://127.0.0.1:8080".parse().unwrap();
        assert_eq!(local.as_str(), "http://127.0.0.1:8080");
        let v6: AllowedOrigin = "http://[::1]:80".parse().unwrap();
        assert_eq!(v6.as_str(), "http://[::1]");
    }

    #[test]
    fn a_malformed_allowed_origin_is_refused_with_the_fix() {
        for (bad, hint) in [
            ("*", "wildcards are not accepted"),
            ("https://*.foxglove.dev", "wildcards are not accepted"),
            (
                "https://app.foxglove.dev/",
                "did you mean https://app.foxglove.dev?",
            ),
            ("app.foxglove.dev", "did you mean https://app.foxglove.dev?"),
            ("ftp://app.foxglove.dev", "SCHEME://HOST[:PORT]"),
            ("https://app.foxglove.dev:99999", "SCHEME://HOST[:PORT]"),
            ("https://-bad.example", "SCHEME://HOST[:PORT]"),
            ("", "SCHEME://HOST[:PORT]"),
        ] {
            let e = bad.parse::<AllowedOrigin>().unwrap_err();
            assert!(e.contains(hint), "{bad:?}: {e}");
        }
    }
}
