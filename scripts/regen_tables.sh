#!/usr/bin/env bash
# Regenerates every committed results/*/table.md (a sweep's table, the paper's claims) from the
# committed result files, by the command in its last line ("Made by `rdpg ...`."), with
# target/release/rdpg, and RESULTS.md's marked copies of them (`<!-- table: results/X/table.md
# -->` above the rows). Run it after committing new result files (`rdpg sweep FILE --collect`);
# the CI test committed_tables_regenerate_from_their_result_files checks both.
set -euo pipefail
cd "$(dirname "$0")/.."
for table in results/*/table.md; do
  command="$(sed -n 's/^Made by `rdpg \(.*\)`\.$/\1/p' "$table" | tail -n 1)"
  [ -n "$command" ] || { echo "$table: no 'Made by' line" >&2; exit 1; }
  # shellcheck disable=SC2086 # the command's words, as the table names them
  target/release/rdpg $command > "$table.new"
  if cmp -s "$table" "$table.new"; then rm "$table.new"; else mv "$table.new" "$table"; echo "updated $table"; fi
done
python3 - <<'PY'
import re
path = "RESULTS.md"
text = open(path).read()
def fill(m):
    # The K-th table of the file (its K-th block of `|` lines): `table.md` marks the first,
    # `table.md, K` the K-th.
    blocks = [[l for l in b.splitlines() if l.startswith("|")]
              for b in open(m.group(1)).read().split("\n\n")]
    rows = [b for b in blocks if b][int(m.group(2) or 1) - 1]
    return m.group(0).split("\n", 1)[0] + "\n" + "\n".join(rows) + "\n"
new = re.sub(r"<!-- table: (results/[^ ]+/table\.md)(?:, (\d+))? -->\n(?:\|[^\n]*\n)*", fill, text)
if new != text:
    open(path, "w").write(new)
    print("updated RESULTS.md")
PY
