//! The accept loop: HTTP/1 connections served by hyper with the limits `axum::serve` leaves
//! unset. A client has `header_timeout` to send a request's headers (one that trickles them is
//! cut off), at most `max_connections` connections are open at once (past that a new one is
//! closed at once, and logged), and on shutdown the loop stops accepting, asks every connection
//! to finish its request in hand, and waits for them. [`bind`] makes the listener with room for
//! as many connections waiting to be accepted as may be open.

use std::{future::Future, net::SocketAddr, sync::Arc, time::Duration};

use axum::Router;
use hyper_util::{
    rt::{TokioIo, TokioTimer},
    service::TowerToHyperService,
};
use tokio::{
    net::{TcpListener, TcpSocket},
    sync::Semaphore,
};

/// Limits on connections.
#[derive(Clone, Copy, Debug)]
pub struct ConnectionLimits {
    /// Time to send a request's headers.
    pub header_timeout: Duration,
    /// Connections open at once.
    pub max_connections: usize,
}

/// Listens on `addr` with room for `backlog` connections waiting to be accepted (the kernel caps
/// it at `net.core.somaxconn`). `TcpListener::bind` leaves room for 128: when a farm's workers
/// all connect at once (a thousand joining, or coming back after a restart), the kernel drops the
/// connections past that, and each waits for its connection attempt to be sent again, one second
/// later, then three, then seven. Must be called inside a tokio runtime.
pub fn bind(addr: SocketAddr, backlog: u32) -> std::io::Result<TcpListener> {
    let socket = if addr.is_ipv4() { TcpSocket::new_v4()? } else { TcpSocket::new_v6()? };
    // As `TcpListener::bind` does: a restarted coordinator gets its port back at once.
    socket.set_reuseaddr(true)?;
    socket.bind(addr)?;
    socket.listen(backlog)
}

/// Serves `app` on `listener` until `shutdown` completes, then lets the open connections finish.
pub(super) async fn serve(
    listener: TcpListener,
    app: Router,
    limits: ConnectionLimits,
    shutdown: impl Future<Output = ()>,
) {
    let permits = Arc::new(Semaphore::new(limits.max_connections.max(1)));
    // Connections watch `stop` to shut down gracefully; `open` closes when the last one ends.
    let (stop, stopping) = tokio::sync::watch::channel(false);
    let (open, all_closed) = tokio::sync::mpsc::channel::<()>(1);
    tokio::pin!(shutdown);
    // Connections closed on arrival (over `max_connections`) since the last log line about them.
    let (mut turned_away, mut last_logged) = (0u64, None::<std::time::Instant>);
    loop {
        let (stream, remote) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(accepted) => accepted,
                Err(e) => {
                    // Out of file descriptors and the like: wait rather than spin.
                    tracing::warn!("accepting a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            _ = &mut shutdown => break,
        };
        let Ok(permit) = permits.clone().try_acquire_owned() else {
            // One line a second at most, with the count: clients retrying in a loop must not
            // flood the log (a thousand workers over the cap wrote 20,000 lines in 5 s).
            turned_away += 1;
            let now = std::time::Instant::now();
            if last_logged.is_none_or(|t| now.duration_since(t) >= Duration::from_secs(1)) {
                tracing::warn!(
                    %remote,
                    "{turned_away} connection(s) closed on arrival since the last such line: {} connections are open, the most this coordinator serves (--max-connections)",
                    limits.max_connections
                );
                last_logged = Some(now);
                turned_away = 0;
            }
            continue;
        };
        let _ = stream.set_nodelay(true);
        let service = TowerToHyperService::new(app.clone());
        let (mut stopping, open) = (stopping.clone(), open.clone());
        tokio::spawn(async move {
            let mut builder = hyper::server::conn::http1::Builder::new();
            builder.timer(TokioTimer::new()).header_read_timeout(limits.header_timeout);
            let conn = builder.serve_connection(TokioIo::new(stream), service);
            tokio::pin!(conn);
            let result = tokio::select! {
                result = conn.as_mut() => result,
                _ = async { stopping.wait_for(|stop| *stop).await.map(|_| ()) } => {
                    conn.as_mut().graceful_shutdown();
                    conn.await
                }
            };
            if let Err(e) = result {
                tracing::debug!(%remote, "connection ended: {e}");
            }
            drop((permit, open));
        });
    }
    drop(listener);
    let _ = stop.send(true);
    drop(open);
    let mut all_closed = all_closed;
    // Resolves when every connection task has dropped its sender.
    let _ = all_closed.recv().await;
}

#[cfg(test)]
mod tests {
    use std::{
        net::TcpStream,
        time::{Duration, Instant},
    };

    #[test]
    fn a_burst_of_connections_waits_in_the_accept_queue() {
        // The kernel caps the backlog at somaxconn: below what the test needs, there is nothing
        // to show.
        let somaxconn: usize = std::fs::read_to_string("/proc/sys/net/core/somaxconn")
            .ok()
            .and_then(|s| s.trim().parse().ok())
            .unwrap_or(4096);
        let burst = 400;
        if somaxconn <= burst {
            return;
        }
        let runtime = tokio::runtime::Builder::new_current_thread().enable_io().build().unwrap();
        let listener =
            runtime.block_on(async { super::bind("127.0.0.1:0".parse().unwrap(), 1024) }).unwrap();
        let addr = listener.local_addr().unwrap();
        // Nobody accepts, as when a busy accept loop has not caught up: with 128 places the
        // 130th connection attempt would be dropped, and not answered within the timeout.
        let start = Instant::now();
        let streams: Vec<TcpStream> = (0..burst)
            .map(|i| {
                TcpStream::connect_timeout(&addr, Duration::from_millis(800))
                    .unwrap_or_else(|e| panic!("connection {i} of {burst}: {e}"))
            })
            .collect();
        assert_eq!(streams.len(), burst);
        assert!(start.elapsed() < Duration::from_secs(5));
    }
}
