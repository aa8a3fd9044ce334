r"""The cascade's view of one hierarchy: its levels' rows, evaluated once per step.

Level :math:`k` holds its equality tasks stacked as :math:`J_k,\ r_k` (CLIK reference
:math:`r = \dot\sigma_d + K\tilde\sigma`, paper eq. 2) and its set tasks as rows
:math:`G\dot q \le h` (:mod:`qp_baseline.set_rows`). :class:`HierarchyLayout` allocates the
buffers once per hierarchy object; :meth:`HierarchyLayout.evaluate` fills them at each step
from one pass of the shared task evaluation (:mod:`tpik.evaluation`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qp_baseline.cascade_kernels import equality_rows
from qp_baseline.set_rows import SetRowBuilder
from robots import Kinematics, Robot
from tpik.evaluation import TaskEvaluation
from tpik.exceptions import InvalidTaskState
from tpik.hierarchy import Hierarchy
from tpik.reference import ControlReference
from tpik.tasks import SetTask, Task


@dataclass
class EqualityRows:
    """One priority level's equality tasks and their rows (buffers, filled at each step).

    Attributes:
        name: Level name.
        tasks: The level's equality tasks, in order.
        J: Stacked Jacobians. Shape (m_eq, n).
        r: Stacked CLIK references. Shape (m_eq,).
    """

    name: str
    tasks: tuple[Task, ...]
    J: np.ndarray
    r: np.ndarray


class HierarchyLayout:
    """The levels of one hierarchy as rows, and the buffers they are evaluated into.

    Args:
        hierarchy: The hierarchy (only read).
        robot: The robot its tasks are evaluated on.
        reference: The control reference (gain cap) of every row.

    Attributes:
        levels: Equality rows of each level, highest priority first.
        first_eq: Index of the first level with equality rows (``len(levels)`` when none has).
        set_tasks: Every set task, level after level.
        set_level: Level of each set task.
        rows: Builder of the set rows.
        G: Set rows that can bind this step, level after level (views, valid for this step). Shape (m, n).
        h: Their bounds. Shape (m,).
        owner: Index into ``set_tasks`` of each row. Shape (m,).
    """

    def __init__(self, hierarchy: Hierarchy, robot: Robot, reference: ControlReference) -> None:
        n = robot.nq
        levels: list[EqualityRows] = []
        set_tasks: list[SetTask] = []
        set_level: list[int] = []
        for k, level in enumerate(hierarchy.levels):
            eq = tuple(t for t in level.tasks if not isinstance(t, SetTask))
            m_eq = sum(task.dim for task in eq)
            levels.append(EqualityRows(level.name, eq, np.zeros((m_eq, n)), np.zeros(m_eq)))
            for task in level.tasks:
                if isinstance(task, SetTask):
                    set_tasks.append(task)
                    set_level.append(k)
        self.levels = levels
        # One evaluation pass over every task (tpik.evaluation): equality tasks level after
        # level, then the set tasks in the order their rows are stacked.
        self._evaluation = TaskEvaluation([*[t for lv in levels for t in lv.tasks], *set_tasks], robot)
        ptr = self._evaluation.eq_ptr
        self._eq_J, self._eq_r = np.zeros((int(ptr[-1]), n)), np.zeros(int(ptr[-1]))
        self._eq_spans: list[tuple[EqualityRows, int, int]] = []
        e = 0
        for lv in levels:
            if lv.tasks:
                self._eq_spans.append((lv, int(ptr[e]), int(ptr[e + len(lv.tasks)])))
            e += len(lv.tasks)
        self.first_eq = next((k for k, lv in enumerate(levels) if lv.r.size), len(levels))
        self.set_tasks = tuple(set_tasks)
        self.set_level = tuple(set_level)
        self.set_names = tuple(t.name for t in set_tasks)
        self._set_level_of = np.array(set_level, dtype=np.int64)
        self._cuts = np.zeros(len(levels) + 1, dtype=np.int64)
        self.rows = SetRowBuilder(self.set_tasks, n, reference)
        self.G, self.h, self.owner = np.zeros((0, n)), np.zeros(0), np.zeros(0, dtype=int)

    def evaluate(self, kin: Kinematics, dt: float, lb: np.ndarray, ub: np.ndarray, method: str) -> list[int]:
        """Evaluate every task once: equality rows into their levels, set rows into ``G``, ``h``, ``owner``.

        The CLIK references (eq. 2) come in one compiled call
        (:func:`~qp_baseline.cascade_kernels.equality_rows`). A set row that cannot reach its
        bound inside the hard box :math:`[lb, ub]` is redundant and dropped
        (:meth:`~qp_baseline.set_rows.SetRowBuilder.binding`).

        Args:
            kin: Kinematics snapshot.
            dt: Control period [s].
            lb: Lower bounds of the hard box [rad/s]. Shape (n,).
            ub: Upper bounds of the hard box [rad/s]. Shape (n,).
            method: Method name, for the error message.

        Returns:
            ``cuts``: the set rows of level k are ``cuts[k]:cuts[k + 1]``.

        Raises:
            InvalidTaskState: An equality task's Jacobian or reference is not finite, or a set
                task's Jacobian (naming the task).
        """
        ev = self._evaluation
        ev.evaluate(kin)
        J, r = self._eq_J, self._eq_r
        if not equality_rows(ev.eq_out, ev.eq_in, ev.eq_ptr, float(dt), self.rows.reference.gain_cap, J, r):
            raise InvalidTaskState(f"{method}: non-finite equality task Jacobian or reference")
        for lv, a, b in self._eq_spans:
            lv.J[...] = J[a:b]
            lv.r[...] = r[a:b]
        self.G, self.h, self.owner = self.rows.binding(ev, dt, lb, ub, self._set_level_of, self._cuts)
        return self._cuts.tolist()  # type: ignore[no-any-return]
