#!/usr/bin/env bash
# The firmware for the Cortex-M7: builds for the real board (STM32H743, firmware/memory.x; also
# with defmt logging) and for QEMU (mps2-an500, firmware/memory-qemu.x), prints their size
# reports (sections, per crate, largest symbols), boots the QEMU self-test with `-icount
# shift=0` (one instruction = one virtual ns) for the instructions per EKF step and the stack
# high-water, and enforces the budgets below. Fails loudly: a missing tool, a failing build or
# self-test, or a budget exceeded ends CI.
set -euo pipefail
cd "$(dirname "$0")/.."
T=thumbv7em-none-eabihf
ELF=target/$T/firmware/firmware

# Budgets. The issue's targets are .text <= 64 KiB, stack <= 16 KiB and <= 30 000 instructions
# per EKF update; where today's firmware does not meet one, CI enforces the measured figure as a
# ratchet (it may only go down) and prints the gap to the target. Lower a ratchet when a change
# wins bytes or instructions; never raise it to make a build pass without saying why.
TEXT_TARGET=$((64 * 1024))
TEXT_RATCHET=$TEXT_TARGET     # STM32H743 .text, bytes (met; docs/measurements.md: how, and the history)
STACK_TARGET=$((16 * 1024))
STACK_RATCHET=$STACK_TARGET  # self-test stack high-water, bytes (met)
INSTR_TARGET=30000
INSTR_RATCHET=21000          # max instructions per EKF update: under the target, so the ratchet
                             # only guards against a regression; lower it when a change wins

sizetool=""
for s in llvm-size size; do command -v "$s" >/dev/null 2>&1 && { sizetool=$s; break; }; done
[ -n "$sizetool" ] || { echo "qemu.sh: no llvm-size or size (binutils) to report the firmware size" >&2; exit 1; }
command -v qemu-system-arm >/dev/null || { echo "qemu.sh: qemu-system-arm missing (run .ci/setup)" >&2; exit 1; }

report() { # $1 = label
  echo "-- $1: $ELF"
  "$sizetool" -A "$ELF" | awk '$1 ~ /^\.(vector_table|text|rodata|data|bss|uninit)$/ {print "   " $1, $2, "bytes"}'
}

section() { "$sizetool" -A "$ELF" | awk -v s="$1" '$1 == s {print $2}'; }
budget() { # $1 = what, $2 = measured, $3 = target, $4 = ratchet (the enforced limit; default: the target)
  local what=$1 v=$2 target=$3 ratchet=${4:-$3}
  # The ratchet is enforced whether it lies above the target (a gap not yet closed) or below it
  # (a guard against regressions where the target is met: 21 200 instructions once passed here).
  if [ "$v" -gt "$ratchet" ]; then
    echo "qemu.sh: budget exceeded: $what = $v > ratchet $ratchet (target $target)" >&2
    exit 1
  elif [ "$v" -le "$target" ]; then
    echo "budget: $what = $v <= target $target (ratchet $ratchet): ok"
  else
    echo "budget: $what = $v: over the target $target by $((v - target)) (not met; ratchet $ratchet holds)"
  fi
}

echo "== firmware: STM32H743 board =="
cargo build -p firmware --profile firmware --target $T
report "STM32H743 (flash: .vector_table+.text+.rodata+.data; RAM: .data+.bss)"
echo "-- STM32H743: where the flash goes"
bash .ci/size-report.sh "$ELF" 15
budget "STM32H743 .text bytes" "$(section .text)" "$TEXT_TARGET" "$TEXT_RATCHET"

echo "== firmware: STM32H743 board with defmt logging (defmt-rtt) =="
cargo build -p firmware --profile firmware --target $T --features defmt --target-dir target/fw-extra
echo "-- defmt build: target/fw-extra/$T/firmware/firmware"
"$sizetool" -A target/fw-extra/$T/firmware/firmware | awk '$1 ~ /^\.(text|rodata|defmt)$/ {print "   " $1, $2, "bytes"}'

echo "== firmware: QEMU mps2-an500 self-test (instructions per EKF step, stack high-water) =="
cargo build -p firmware --profile firmware --target $T --features board-qemu,selftest
timeout 300 qemu-system-arm -M mps2-an500 -nographic -icount shift=0 \
  -semihosting-config enable=on,target=native -kernel "$ELF" | tee /tmp/driftid-selftest.log
grep -q "instructions per update" /tmp/driftid-selftest.log || { echo "qemu.sh: self-test printed no figures" >&2; exit 1; }
grep -q "checkpoint round trip: ok" /tmp/driftid-selftest.log || { echo "qemu.sh: self-test checkpoint round trip failed" >&2; exit 1; }
instr_max=$(sed -n 's/.*instructions per update: mean [0-9]* (min [0-9]*, max \([0-9]*\)).*/\1/p' /tmp/driftid-selftest.log)
stack=$(sed -n 's/^stack high-water \([0-9]*\) of.*/\1/p' /tmp/driftid-selftest.log)
[ -n "$instr_max" ] && [ -n "$stack" ] || { echo "qemu.sh: could not read the self-test figures" >&2; exit 1; }
budget "instructions per EKF update (max)" "$instr_max" "$INSTR_TARGET" "$INSTR_RATCHET"
budget "stack high-water bytes (self-test)" "$stack" "$STACK_TARGET" "$STACK_RATCHET"

echo "== firmware: QEMU mps2-an500 link build (the image the qemu end-to-end tests boot) =="
cargo build -p firmware --profile firmware --target $T --features board-qemu
report "QEMU mps2-an500"

echo "== firmware: a panic, a HardFault and a stack overflow under QEMU end the run with a failure code (no hang) =="
for crash in panic hardfault stackoverflow; do
  # One target dir for the three and the defmt build (they differ in the firmware crate's features only).
  cargo build -q -p firmware --profile firmware --target $T --features board-qemu,crash-$crash --target-dir target/fw-extra
  set +e
  timeout 60 qemu-system-arm -M mps2-an500 -display none -monitor none -serial null -semihosting-config enable=on,target=native \
    -kernel target/fw-extra/$T/firmware/firmware > /tmp/driftid-crash-$crash.log 2>&1
  rc=$?
  set -e
  head -3 /tmp/driftid-crash-$crash.log
  [ "$rc" -ne 124 ] || { echo "qemu.sh: crash-$crash: QEMU hung (timeout)" >&2; exit 1; }
  [ "$rc" -ne 0 ] || { echo "qemu.sh: crash-$crash: QEMU exited with success after a crash" >&2; exit 1; }
  if [ "$crash" = stackoverflow ]; then
    # flip-link: the stack runs off the start of RAM and faults; with no stack left for the
    # HardFault handler the core locks up, which QEMU reports and ends with a failure code.
    grep -qiE "firmware fatal|Lockup" /tmp/driftid-crash-$crash.log || { echo "qemu.sh: crash-$crash: no fault or lockup" >&2; exit 1; }
  else
    grep -qi "firmware fatal" /tmp/driftid-crash-$crash.log || { echo "qemu.sh: crash-$crash: no fault report" >&2; exit 1; }
  fi
  echo "crash-$crash: QEMU exit code $rc (failure, as required)"
done
