#!/usr/bin/env bash
# Where the firmware's flash goes: code and read-only data by crate (demangled symbol paths,
# summed), then the largest symbols. Usage: size-report.sh ELF [N largest symbols]
set -euo pipefail
elf=$1; top=${2:-15}
nmtool=""
for n in llvm-nm nm; do command -v "$n" >/dev/null 2>&1 && { nmtool=$n; break; }; done
[ -n "$nmtool" ] || { echo "size-report: no nm (binutils)" >&2; exit 1; }
# --size-sort -S: address, size, type, name (sizes in decimal with --radix=d); t/T code, r/R rodata.
# Legacy-mangled generic names come out half-demangled ($LT$ ...): finish the job.
demangle() { sed -e 's/\$LT\$/</g; s/\$GT\$/>/g; s/\$RF\$/\&/g; s/\$u20\$/ /g; s/\$C\$/,/g; s/\$u27\$/'"'"'/g; s/\$BP\$/*/g; s/\.\./::/g; s/ _</ </g; s/::h[0-9a-f]\{16\}$//'; }
"$nmtool" -C -S --size-sort --radix=d "$elf" | demangle | awk '
  NF >= 4 && ($3 ~ /^[tTrR]$/) {
    # The linker folds identical functions (--icf=all, firmware/build.rs): one copy under
    # several names at one address, counted once (for the first name listed).
    if (at[$1 " " $2]++) next;
    size = $2 + 0; kind = ($3 ~ /[tT]/) ? "text" : "rodata";
    name = $4; for (i = 5; i <= NF; i++) name = name " " $i;
    # The crate: the first path segment, after "<", "&", "impl " and "dyn " (trait impls name
    # the type first: <nalgebra::...Matrix as core::fmt::Debug>::fmt counts for nalgebra).
    c = name; sub(/^(<|&|mut |dyn |impl )+/, "", c); sub(/^(<|&|mut |dyn |impl )+/, "", c);
    if (c ~ /::/) { sub(/::.*/, "", c) } else { c = "(no crate path: " (kind == "text" ? "compiler-builtins, asm" : "anonymous constants") ")" }
    sub(/<.*/, "", c);
    if (c ~ /^([iu](8|16|32|64|128|size)|f32|f64|str|bool|char) as /) c = "core";
    by[c " " kind] += size; total[kind] += size;
    syms[NR] = size "\t" kind "\t" name;
  }
  END {
    printf "   %-44s %9s %9s\n", "crate", ".text", ".rodata";
    for (k in by) { split(k, p, " "); crate = substr(k, 1, length(k) - length(p[length(p)]) - 1); seen[crate] = 1 }
    n = 0; for (c in seen) { n++; order[n] = c }
    # sort by text size, descending (simple insertion sort: few crates)
    for (i = 2; i <= n; i++) { v = order[i]; j = i - 1; while (j > 0 && by[order[j] " text"] < by[v " text"]) { order[j + 1] = order[j]; j-- } order[j + 1] = v }
    for (i = 1; i <= n; i++) printf "   %-44s %9d %9d\n", substr(order[i], 1, 44), by[order[i] " text"], by[order[i] " rodata"];
    printf "   %-44s %9d %9d\n", "total (sized symbols)", total["text"], total["rodata"];
  }'
echo "   largest $top symbols (bytes, section, name):"
"$nmtool" -C -S --size-sort --radix=d "$elf" | demangle | awk '$3 ~ /^[tTrR]$/' | tail -n "$top" | sort -k2,2nr \
  | awk '{ name = $4; for (i = 5; i <= NF; i++) name = name " " $i; printf "   %7d %s %s\n", $2, ($3 ~ /[tT]/ ? ".text  " : ".rodata"), substr(name, 1, 110) }'
