#!/usr/bin/env bash
# Mutation testing of the safety modules (a developer's tool: not in CI, not a dependency).
#
#   .mutation/run.sh MODULE [MUTANT_NAME_OR_PATTERN...]   MODULE: a key of the table below, or "list"
#
# Patterns (fnmatch, e.g. '*ǁSimOdriveAxisǁ_check_watchdog*') restrict the run and the score to
# those mutants (mutmut names a method's mutants module.xǁClassǁmethod__mutmut_N).
#
# Each module is mutated against its own test files only (mutmut runs, for each mutant, only the
# tests that call the mutated function), so one module fits a 2-core machine in minutes. The
# project (or the tree $MUTATION_SOURCE, e.g. an earlier commit's `git archive` for the scores
# before) is copied to $MUTATION_WORK/<MODULE>/ (default /tmp/es-mutation): mutmut's mutants/
# folder never lands in the work tree. Needs mutmut 3 (pip install 'mutmut==3.8.1'; a venv is
# best: python3 -m venv --system-site-packages /tmp/mm && /tmp/mm/bin/pip install mutmut==3.8.1,
# then MUTMUT=/tmp/mm/bin/mutmut). Prints the surviving mutants and one summary line:
#   MODULE: killed K / total T (survived S, no tests N, timeout O, other X)
# The score table and the reasons each remaining survivor is equivalent: docs/mutation.md.
set -euo pipefail

here="${MUTATION_SOURCE:-$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)}"  # the tree to copy
work_root="${MUTATION_WORK:-/tmp/es-mutation}"
mutmut="${MUTMUT:-mutmut}"
children="${MUTATION_CHILDREN:-2}"

# key | file to mutate | its test files (space separated; globs expanded in the copy)
table='
bus|controller/io/bus.py|tests/controller/io/test_bus*.py
contract|protocol/contract.py|tests/protocol/test_contract*.py tests/protocol/test_strict_decode.py tests/protocol/test_reference.py
supervisor|controller/supervisor.py|tests/controller/test_supervisor*.py
weights|controller/stepping/weights.py|tests/controller/stepping/test_weights*.py
atomic|controller/atomic.py|tests/controller/test_atomic*.py
axis|controller/io/axis.py|tests/controller/io/test_axis*.py tests/controller/io/test_bus*.py
odrive_axis|firmware_sim/odrive_axis.py|tests/firmware_sim/test_odrive_axis*.py
schema|controller/settings/schema.py|tests/controller/settings/test_file.py tests/controller/settings/test_schema*.py
'

module="${1:-}"
shift || true
if [[ -z "$module" || "$module" == list ]]; then
    echo "modules:"; echo "$table" | sed '/^$/d; s/|/  /g'
    [[ "$module" == list ]] && exit 0 || exit 2
fi
row="$(echo "$table" | grep "^${module}|" || true)"
if [[ -z "$row" ]]; then
    echo "run.sh: error: unknown module '$module' (see: run.sh list)" >&2
    exit 2
fi
IFS='|' read -r _ target tests <<<"$row"
if [[ ! -f "$here/pyproject.toml" || ! -f "$here/$target" ]]; then
    echo "run.sh: error: $here is not an elegant-stepping tree (no pyproject.toml or $target)" >&2
    exit 3
fi

dest="$work_root/$module"
rm -rf "$dest"
mkdir -p "$dest"
# The copy: everything but git, caches and earlier mutants.
(cd "$here" && tar --exclude=./.git --exclude=./out --exclude='*/mutants' --exclude='__pycache__' \
    --exclude='.pytest_cache' --exclude='.hypothesis' --exclude='*.egg-info' -cf - .) | tar -xf - -C "$dest"
cd "$dest"
expanded=()
for pattern in $tests; do
    for f in $pattern; do [[ -e "$f" ]] && expanded+=("$f"); done
done
if [[ ${#expanded[@]} -eq 0 ]]; then
    echo "run.sh: error: no test file matches '$tests'" >&2
    exit 3
fi
{
    echo "[mutmut]"
    echo "source_paths ="
    printf '    %s\n' controller/ protocol/ firmware_sim/
    echo "only_mutate = $target"
    echo "also_copy ="
    printf '    %s\n' hil/ configs/ urdf/ deploy/ docs/ README.md
    echo "pytest_add_cli_args_test_selection ="
    printf '    %s\n' "${expanded[@]}"
    echo "pytest_add_cli_args ="
    printf '    %s\n' -p no:cacheprovider -p no:randomly
    echo "use_git_change_detection = false"
} >setup.cfg

echo "mutating $target against ${expanded[*]} in $dest"
nice -n 10 "$mutmut" run --max-children "$children" "$@" >"$dest/mutmut-run.log" 2>&1 || {
    echo "run.sh: mutmut run failed; the end of $dest/mutmut-run.log:" >&2
    tail -30 "$dest/mutmut-run.log" >&2
    exit 1
}
"$mutmut" results --all true >"$dest/results.txt" 2>/dev/null
python3 - "$module" "$dest/results.txt" "$@" <<'PY'
import collections, fnmatch, sys
# only the mutants asked for, when names or patterns were given (mutmut lists the others "not checked")
patterns = [a for a in sys.argv[3:] if not a.startswith("-")]
rows = [line.strip().rsplit(": ", 1) for line in open(sys.argv[2]) if ": " in line]
rows = [(name, status) for name, status in rows
        if not patterns or any(fnmatch.fnmatch(name, p) for p in patterns)]
for name, status in rows:
    if status != "killed":
        print(f"    {name}: {status}")
counts = collections.Counter(status for _, status in rows)
total = sum(counts.values())
other = total - sum(counts[k] for k in ("killed", "survived", "no tests", "timeout"))
print(f"{sys.argv[1]}: killed {counts['killed']} / total {total} (survived {counts['survived']}, "
      f"no tests {counts['no tests']}, timeout {counts['timeout']}, other {other})")
PY
