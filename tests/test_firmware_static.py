"""Static checks of the firmware's hot path that the 64-bit unix port cannot make.

On a 32-bit board an integer >= 2^30 is a heap-allocated big int: in the sampler
interrupt that is an allocation (forbidden in a hard ISR), in the main loop a
garbage collection that delays sampling. The unix port's small ints reach 2^62,
so the heap-lock test cannot see it: this test reads the source instead.
"""

import ast

import pytest

from conftest import FIRMWARE

SMALL = 1 << 30
# module -> functions on the hot path (None: the whole module)
HOT = {
    "sampler.py": None,
    "ring.py": None,
    "pulses.py": None,
    "adc_scan.py": ["latch", "skip", "_reader"],
    "servo_pio.py": ["_drain", "read"],
    "servo_pcnt.py": ["_edge", "_poll", "_learn_period", "_place", "read"],
    "hall_pcnt.py": ["_edge", "_poll", "snap"],
    "codec.py": ["crc32_store", "cobs_encode", "copy_bytes", "FrameEncoder"],
    "app.py": ["_send", "send_hello", "send_hello_compact", "send_status", "pump", "service",
               "feed_watchdog", "check_escape", "_poll_ready"],
}


def big_literals(tree: ast.AST, names):
    """(line, value) of every int literal >= 2^30 inside the named functions/classes."""
    roots = [tree] if names is None else [n for n in ast.walk(tree)
                                          if isinstance(n, (ast.FunctionDef, ast.ClassDef)) and n.name in names]
    found = []
    for root in roots:
        for node in ast.walk(root):
            if isinstance(node, ast.Constant) and type(node.value) is int and abs(node.value) >= SMALL:
                found.append((node.lineno, node.value))
    return roots, found


@pytest.mark.parametrize("module", sorted(HOT))
def test_hot_path_has_no_integer_literal_of_2_30_or_more(module):
    tree = ast.parse((FIRMWARE / module).read_text())
    roots, found = big_literals(tree, HOT[module])
    if HOT[module] is not None:
        assert {r.name for r in roots} == set(HOT[module]), "a hot-path function was renamed: update HOT"
    assert not found, f"{module}: integer literals >= 2^30 on the hot path (line, value): {found}"


def test_the_check_finds_a_big_literal():
    tree = ast.parse("def isr(t):\n    return t & 0xFFFFFFFF\n")
    assert big_literals(tree, ["isr"])[1] == [(2, 0xFFFFFFFF)]


# names that hold ticks (time.ticks_us / ticks_ms values) in the firmware
TICK_NAMES = {"t", "tf", "tl", "now", "t_isr", "_t_next", "t_last", "t_prev", "t0", "_t", "t_fall", "f_prev",
              "t_free", "_t_rise", "t_read", "_stale", "s_t", "t_a", "t_b", "t_start", "before",
              "t_first_nominal"}


def tick_arithmetic(tree: ast.AST):
    """(line, expression) of every + or - with a ticks value as an operand: on a board,
    ticks combine only through time.ticks_add / ticks_diff (t + period before a mask is an
    int >= 2^30 near the wrap: a heap object, in a hard interrupt a MemoryError)."""
    def name(n):
        return n.id if isinstance(n, ast.Name) else n.attr if isinstance(n, ast.Attribute) else None

    return [(node.lineno, ast.unparse(node)) for node in ast.walk(tree)
            if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub))
            and (name(node.left) in TICK_NAMES or name(node.right) in TICK_NAMES)]


@pytest.mark.parametrize("module", sorted(p.name for p in FIRMWARE.glob("*.py")))
def test_ticks_combine_only_through_ticks_add_and_ticks_diff(module):
    found = tick_arithmetic(ast.parse((FIRMWARE / module).read_text()))
    assert not found, f"{module}: ticks combined by + or - (line, expression): {found}"


def test_the_tick_check_finds_the_old_sampler_step():
    tree = ast.parse("def isr(self):\n    self._t_next = (self._t_next + self.period_us) & 0x3FFFFFFF\n")
    assert tick_arithmetic(tree) == [(2, "self._t_next + self.period_us")]
