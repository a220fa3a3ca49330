"""What the conformance checker found: problems (capped per kind, all counted) and how to print them."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

DEFAULT_MAX_PER_KIND = 20


@dataclass(frozen=True)
class Problem:
    """One conformance failure: where (table, record token, field) and what is wrong."""

    table: str
    token: str
    field: str
    message: str
    check: str = ""  # kind of check, e.g. "foreign_key"; the cap counts per (table, field, check)


@dataclass
class ValidationReport:
    """Problems found (capped per kind) plus the true count of each kind and the table sizes."""

    dataroot: Path
    version: str
    max_per_kind: int = DEFAULT_MAX_PER_KIND
    problems: list[Problem] = field(default_factory=list)
    kind_counts: Counter = field(default_factory=Counter)
    table_counts: dict[str, int] = field(default_factory=dict)

    def add(self, table: str, token: str, field_: str, message: str, check: str) -> None:
        kind = (table, field_, check)
        self.kind_counts[kind] += 1
        if self.kind_counts[kind] <= self.max_per_kind:
            self.problems.append(Problem(table, token, field_, message, check))

    @property
    def ok(self) -> bool:
        return not self.kind_counts

    @property
    def n_problems(self) -> int:
        """All problems found, including those beyond the per-kind cap."""
        return sum(self.kind_counts.values())

    def suppressed(self) -> dict[tuple[str, str, str], int]:
        """(table, field, check) -> how many problems of that kind were counted but not kept."""
        return {k: n - self.max_per_kind for k, n in self.kind_counts.items() if n > self.max_per_kind}

    def format_text(self) -> str:
        """Problems grouped by table, or a one-line OK with the row count of every table."""
        if self.ok:
            counts = ", ".join(f"{t} {n}" for t, n in self.table_counts.items())
            return f"OK: {self.dataroot} version {self.version} conforms ({counts})"
        lines = [f"FAIL: {self.dataroot} version {self.version}: {self.n_problems} problem(s)"]
        hidden = self.suppressed()
        for table in dict.fromkeys(t for t, _, _ in self.kind_counts):
            n_table = sum(n for (t, _, _), n in self.kind_counts.items() if t == table)
            lines.append(f"[{table or 'database'}] {n_table} problem(s)")
            for p in (p for p in self.problems if p.table == table):
                where = " ".join(s for s in (p.token, p.field) if s)
                lines.append(f"  {p.check}: {where + ': ' if where else ''}{p.message}")
            for (t, f, c), n in hidden.items():
                if t == table:
                    lines.append(f"  {c}: ... and {n} more {f or 'record'} problem(s) of this kind")
        return "\n".join(lines)

    def to_json(self) -> dict:
        return {"dataroot": str(self.dataroot), "version": self.version, "ok": self.ok,
                "n_problems": self.n_problems, "table_counts": self.table_counts,
                "problems": [vars(p) for p in self.problems],
                "suppressed": [{"table": t, "field": f, "check": c, "count": n}
                               for (t, f, c), n in self.suppressed().items()]}
