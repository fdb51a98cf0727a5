"""The kernel's progress lines become one progress bar on a terminal; every other line of its
output is kept, in order. The lines are written here in the kernel's Fortran format
(capsule_model: '(a,f9.3,a,f0.1,a)'), not taken from the code under test."""
from __future__ import annotations

import io

from capsmech.workflow.simulate import relay_kernel_output


def kernel_progress_line(t: float, t_max: float, d12: float) -> str:
    return f"capsim: t = {t:9.3f} / {t_max:.1f}  D12 = {d12:8.5f}  L1/a =   1.0176  area/4pi =   0.995\n"


OTHER = ["capsim: 1926 degrees of freedom, dt =  3.45E-02, 1 threads\n",
         "capsim: steady: over the last time unit the area varied by 5.8E-07 of 4 pi a^2\n",
         "capsim: wrote x.h5 (7.26 s)\n"]
TIMES = [0.5 + 0.01 * k for k in range(300)]
KERNEL_OUTPUT = [OTHER[0], *(kernel_progress_line(t, 60.0, 0.0206) for t in TIMES), *OTHER[1:]]


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_on_a_terminal_the_progress_lines_are_one_bar_and_the_rest_is_kept():
    out = Terminal()
    relay_kernel_output(KERNEL_OUTPUT, out)
    text = out.getvalue()
    assert "capsim: t =" not in text
    # The other lines, in order, each on a line of its own.
    lines = [line + "\n" for line in text.replace("\r", "\n").splitlines()]
    positions = [lines.index(line) for line in OTHER]
    assert positions == sorted(positions)
    # The bar ends where the run did (the steady state, well before t_max), with its measures.
    final_bar = lines[positions[1] - 1]
    assert f"{TIMES[-1]:.2f}/60" in final_bar and "D12 = 0.02060" in final_bar


def test_elsewhere_the_output_is_left_as_the_kernel_wrote_it():
    out = io.StringIO()                    # not a terminal: a log keeps every line
    relay_kernel_output(KERNEL_OUTPUT, out)
    assert out.getvalue() == "".join(KERNEL_OUTPUT)
    forced = Terminal()
    relay_kernel_output(KERNEL_OUTPUT, forced, bar=False)
    assert forced.getvalue() == "".join(KERNEL_OUTPUT)
