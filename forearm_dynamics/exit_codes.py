"""Exit codes of every forearm_dynamics program, defined once.

They mean correctness, never speed: a slow machine is reported, not failed (a latency
threshold gates the exit code only when the user asks for one).
"""

from __future__ import annotations

#: Everything asked was done and the data are right.
OK = 0
#: The data are wrong or lost: a torque off its reference, a message unanswered, a write
#: that failed mid-recording, a regression beyond its tolerance, an asked-for threshold
#: exceeded.
DATA = 1
#: The program could not do what was asked: a bad argument or parameter, a missing,
#: foreign, empty or unreadable input file. One line on stderr names the problem.
USAGE = 2
