//! Publish-to-receive latency and throughput of the iceoryx2 transport for chunk-sized
//! payloads, against a plain memcpy of the same bytes (`bench/transport.md`).
//!
//! ```sh
//! cargo run --release -p ess-actor --example shm_transport            # all sizes
//! cargo run --release -p ess-actor --example shm_transport -- 200     # repetitions
//! ```
//!
//! The process re-runs itself as the receiver. Per message the sender loans a `[u64]`
//! sample (zero-filled, as an actor's chunk is), stamps the wall clock into its first
//! word, publishes it and notifies the receiver's event; the receiver wakes, receives,
//! computes the one-way delay, copies the payload into a `Vec` (as the learner's
//! `read_chunk` does) and answers with the delay on a small service. Reported: median
//! one-way delay publish -> receive (sample already written), median round trip
//! loan+fill -> receive+copy -> answer, and the memcpy of the same bytes.

use iceoryx2::prelude::*;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

type Ipc = ipc::Service;
const SIZES: [usize; 8] = [
    4 << 10,
    16 << 10,
    64 << 10,
    256 << 10,
    1 << 20,
    2 << 20,
    4 << 20,
    8 << 20,
];

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

type AnyErr = Box<dyn std::error::Error>;

type PubSub<T> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, T, ()>;
type Event = iceoryx2::service::port_factory::event::PortFactory<Ipc>;

/// Payload, answer, wake-receiver and wake-sender services.
type Services = (PubSub<[u64]>, PubSub<u64>, Event, Event);

fn services(node: &Node<Ipc>, tag: &str) -> Result<Services, AnyErr> {
    let data = node
        .service_builder(&format!("ess-bench/{tag}/data").as_str().try_into()?)
        .publish_subscribe::<[u64]>()
        .subscriber_max_buffer_size(2)
        .open_or_create()?;
    let ack = node
        .service_builder(&format!("ess-bench/{tag}/ack").as_str().try_into()?)
        .publish_subscribe::<u64>()
        .subscriber_max_buffer_size(4)
        .open_or_create()?;
    let ping = node
        .service_builder(&format!("ess-bench/{tag}/ping").as_str().try_into()?)
        .event()
        .open_or_create()?;
    let pong = node
        .service_builder(&format!("ess-bench/{tag}/pong").as_str().try_into()?)
        .event()
        .open_or_create()?;
    Ok((data, ack, ping, pong))
}

fn receiver(tag: &str) -> Result<(), AnyErr> {
    let node = NodeBuilder::new().create::<Ipc>()?;
    let (data, ack, ping, pong) = services(&node, tag)?;
    let sub = data.subscriber_builder().create()?;
    let ack = ack.publisher_builder().create()?;
    let listener = ping.listener_builder().create()?;
    let notifier = pong.notifier_builder().create()?;
    let mut sink: Vec<u64> = Vec::new();
    // Tell the sender we are connected.
    notifier.notify()?;
    loop {
        listener.timed_wait(|_| {}, Duration::from_secs(5))?;
        while let Some(s) = sub.receive()? {
            let p = s.payload();
            let delay = now_ns().saturating_sub(p[0]);
            if p.len() == 1 && p[0] == 0 {
                return Ok(());
            }
            sink.clear();
            sink.extend_from_slice(p);
            std::hint::black_box(&sink);
            ack.send_copy(delay)?;
            notifier.notify()?;
        }
    }
}

fn main() -> Result<(), AnyErr> {
    set_log_level(LogLevel::Error);
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("--receive") {
        return receiver(&args[2]);
    }
    let reps: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(100);
    let tag = format!("{}", std::process::id());
    let node = NodeBuilder::new().create::<Ipc>()?;
    let (data, ack, ping, pong) = services(&node, &tag)?;
    let publisher = data
        .publisher_builder()
        .initial_max_slice_len(SIZES[SIZES.len() - 1] / 8)
        .create()?;
    let acks = ack.subscriber_builder().create()?;
    let notifier = ping.notifier_builder().create()?;
    let listener = pong.listener_builder().create()?;
    let mut child = std::process::Command::new(std::env::current_exe()?)
        .args(["--receive", &tag])
        .spawn()?;
    listener.timed_wait(|_| {}, Duration::from_secs(10))?;
    println!(
        "| payload | memcpy | publish -> receive (one way) | round trip incl. fill + receiver copy | effective GB/s (round trip) |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for &size in &SIZES {
        let words = size / 8;
        // memcpy of the same bytes.
        let src = vec![1u8; size];
        let mut dst = vec![0u8; size];
        let mut mc = Vec::with_capacity(reps);
        for _ in 0..reps {
            let t = Instant::now();
            dst.copy_from_slice(std::hint::black_box(&src));
            std::hint::black_box(&dst);
            mc.push(t.elapsed().as_secs_f64());
        }
        let (mut one_way, mut rtt) = (Vec::new(), Vec::new());
        for r in 0..reps + 5 {
            let t = Instant::now();
            let mut s = publisher.loan_slice(words)?;
            s.payload_mut()[words - 1] = r as u64;
            s.payload_mut()[0] = now_ns();
            s.send()?;
            notifier.notify()?;
            let got = loop {
                listener.timed_wait(|_| {}, Duration::from_secs(5))?;
                if let Some(a) = acks.receive()? {
                    break *a.payload();
                }
            };
            if r >= 5 {
                rtt.push(t.elapsed().as_secs_f64());
                one_way.push(got as f64 * 1e-9);
            }
        }
        let (mc, ow, rt) = (median(&mut mc), median(&mut one_way), median(&mut rtt));
        let label = if size >= 1 << 20 {
            format!("{} MiB", size >> 20)
        } else {
            format!("{} KiB", size >> 10)
        };
        println!(
            "| {label} | {:.1} µs | {:.1} µs | {:.1} µs | {:.2} |",
            mc * 1e6,
            ow * 1e6,
            rt * 1e6,
            size as f64 / rt / 1e9
        );
    }
    let mut s = publisher.loan_slice(1)?;
    s.payload_mut()[0] = 0;
    s.send()?;
    notifier.notify()?;
    child.wait()?;
    Ok(())
}
