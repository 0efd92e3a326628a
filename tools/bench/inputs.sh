# Sourced by the bench scripts that run on c2m_bench_inputs' files: builds the release asbuilt
# and the generator, and writes the inputs into $OUT once (2 M noisy bunny points in scan order
# and shuffled, a 1 M-triangle column and its scan).
cargo build --release --locked -p asbuilt-tools --bin asbuilt --example c2m_bench_inputs
mkdir -p "$OUT"
[ -f "$OUT/column_scan.ply" ] || target/release/examples/c2m_bench_inputs "$OUT"
