//! Prints what a C3D take holds: `cargo run -p softcap_capture --example c3d_info -- FILE...`.
fn main() {
    for a in std::env::args().skip(1) {
        match softcap_capture::read_c3d(std::path::Path::new(&a)) {
            Ok(t) => {
                let valid = t
                    .positions_m
                    .iter()
                    .flatten()
                    .filter(|p| p.is_some())
                    .count();
                println!(
                    "{a}: {} markers, {} frames at {} Hz (first {}), {valid} valid points; {} analog channels at {} Hz, {} samples each; first labels {:?}; analog {:?} units {:?}",
                    t.marker_labels.len(),
                    t.frames(),
                    t.frame_rate_hz,
                    t.first_frame,
                    t.analog.labels.len(),
                    t.analog.rate_hz,
                    t.analog.samples.first().map_or(0, Vec::len),
                    &t.marker_labels[..t.marker_labels.len().min(4)],
                    &t.analog.labels[..t.analog.labels.len().min(6)],
                    &t.analog.units[..t.analog.units.len().min(6)],
                );
                println!("  analog labels: {:?}", t.analog.labels);
            }
            Err(e) => println!("{e}"),
        }
    }
}
