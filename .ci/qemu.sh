#!/usr/bin/env bash
# The firmware for the Cortex-M7: builds for the real board (STM32H743, memory.x) and for QEMU
# (mps2-an500, memory-qemu.x), prints their size reports, and boots the QEMU self-test with
# `-icount shift=0` (one instruction = one virtual ns) for the instructions per EKF step.
# Fails loudly: a missing tool or a failing build or self-test ends CI.
set -euo pipefail
cd "$(dirname "$0")/.."
T=thumbv7em-none-eabihf
ELF=target/$T/release/firmware

sizetool=""
for s in llvm-size size; do command -v "$s" >/dev/null 2>&1 && { sizetool=$s; break; }; done
[ -n "$sizetool" ] || { echo "qemu.sh: no llvm-size or size (binutils) to report the firmware size" >&2; exit 1; }
command -v qemu-system-arm >/dev/null || { echo "qemu.sh: qemu-system-arm missing (run .ci/setup)" >&2; exit 1; }

report() { # $1 = label
  echo "-- $1: $ELF"
  "$sizetool" -A "$ELF" | awk '$1 ~ /^\.(vector_table|text|rodata|data|bss|uninit)$/ {print "   " $1, $2, "bytes"}'
}

echo "== firmware: STM32H743 board =="
cargo build -p firmware --release --target $T
report "STM32H743 (flash: .vector_table+.text+.rodata+.data; RAM: .data+.bss)"

echo "== firmware: QEMU mps2-an500 self-test (instructions per EKF step, stack high-water) =="
cargo build -p firmware --release --target $T --features board-qemu,selftest
timeout 300 qemu-system-arm -M mps2-an500 -nographic -icount shift=0 \
  -semihosting-config enable=on,target=native -kernel "$ELF" | tee /tmp/driftid-selftest.log
grep -q "instructions per update" /tmp/driftid-selftest.log || { echo "qemu.sh: self-test printed no figures" >&2; exit 1; }

echo "== firmware: QEMU mps2-an500 link build (the image the qemu end-to-end tests boot) =="
cargo build -p firmware --release --target $T --features board-qemu
report "QEMU mps2-an500"

echo "== firmware: a panic and a HardFault under QEMU end the run with a failure code (no hang) =="
for crash in panic hardfault; do
  cargo build -q -p firmware --release --target $T --features board-qemu,crash-$crash --target-dir target/crash-$crash
  set +e
  timeout 60 qemu-system-arm -M mps2-an500 -display none -monitor none -serial null -semihosting-config enable=on,target=native \
    -kernel target/crash-$crash/$T/release/firmware > /tmp/driftid-crash-$crash.log 2>&1
  rc=$?
  set -e
  cat /tmp/driftid-crash-$crash.log
  [ "$rc" -ne 124 ] || { echo "qemu.sh: crash-$crash: QEMU hung (timeout)" >&2; exit 1; }
  [ "$rc" -ne 0 ] || { echo "qemu.sh: crash-$crash: QEMU exited with success after a crash" >&2; exit 1; }
  grep -qi "firmware fatal" /tmp/driftid-crash-$crash.log || { echo "qemu.sh: crash-$crash: no fault report" >&2; exit 1; }
  echo "crash-$crash: QEMU exit code $rc (failure, as required)"
done
