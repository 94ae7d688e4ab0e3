"""A bounded Bayes tree for :func:`~odofuse.estimators.graph.isam2.run_isam2`.

Owns :class:`KeyframeWindow`: the oldest keyframes of an iSAM2 run are marginalised out of
iSAM2 in batches (``ISAM2.marginalizeLeaves``), while a copy of every factor and the
estimate each marginalised variable had when it left are kept for the final batch pass.

Why: in the GTSAM 4.3 wheel every ``ISAM2.update`` destroys the local Bayes tree of the
re-eliminated top, and ``BayesTree::~BayesTree`` walks (breadth first, to avoid recursion)
every clique below its roots, i.e. the whole old tree re-attached beneath them. That walk is
O(n) per update: on Plaza1 without calibration ``perf`` puts 23 % of the run in it and the
median update grows 8x from the first to the last quarter. A tree that never holds more
than ``KEEP + EVERY`` keyframes keeps that walk bounded.

What is given up: a marginalised keyframe is no longer relinearised by iSAM2 (its factors
become one linear factor on what it was connected to, at the linearisation point it had).
Only the online estimates feel it; the offline result is the batch LM optimum of the *whole*
graph (:attr:`KeyframeWindow.graph`), started from :meth:`KeyframeWindow.estimate`.

The SLAM path (:func:`~odofuse.estimators.graph.isam2_slam.incremental_slam`) uses the same
window: landmarks stay in iSAM2 (a landmark whose observing poses left keeps their marginal
factor), and :attr:`KeyframeWindow.hold` keeps in the tree every keyframe from the oldest
one that a factor still to come (a landmark seen again after leaving the window) refers to;
with range-only landmarks the caller holds every keyframe (no window). So do both paths when
a loop closure reaches further back than the window (:meth:`KeyframeWindow.loops_reach_back`).
"""

from __future__ import annotations

# Keyframes kept in iSAM2's tree, and the batch size in which older ones leave it. A
# marginalising update re-eliminates the whole (bounded) tree so that the leaving keyframes
# are eliminated first (the leaves that ``marginalizeLeaves`` requires); batching spreads
# that cost over ``EVERY`` updates. Chosen for latency alone (docs/graph.md, "Measured
# benchmark figures"): with 300 / 100 every 100th update re-eliminated 400 keyframes and
# those 1 % spikes set the p99 unevenly across a log's quarters (1 h log, last/first p99
# 2.68x); 125 keyframes every 25th update are 4 % of every quarter (0.94x), medians within
# 1.5x in all four judged cases, packaged-config accuracy unchanged to the printed digit.
KEEP = 100
EVERY = 25


class KeyframeWindow:
    """The keyframes of one iSAM2 run, the oldest marginalised out of iSAM2 in batches.

    Only pose keys ``x<i>`` and the private pinned beacon copies ``b<n>`` of a keyframe's
    ranges leave; calibration vectors, walking-bias segments and shared landmarks stay in
    iSAM2 for the whole run.

    Attributes
    ----------
    graph : gtsam.NonlinearFactorGraph
        Every factor given to iSAM2, in order (the full graph for the final pass).
    first : int
        The oldest keyframe still in iSAM2.
    marginalised : int
        Keyframes marginalised so far.
    hold : int or None
        Set by the caller: no keyframe from ``hold`` on leaves (a factor that will still be
        added refers to it).
    """

    def __init__(self):
        import gtsam

        self.gtsam = gtsam
        self.graph = gtsam.NonlinearFactorGraph()
        self._taken = gtsam.Values()  # marginalised keys at their estimate when they left
        self._added: list[list[int]] = []  # per keyframe, the x / b keys it added
        self.first = 0
        self.marginalised = 0
        self.hold: int | None = None

    @staticmethod
    def loops_reach_back(loops) -> bool:
        """Whether a loop closure (``graph.loops.Loop``) reaches further back than the window:
        its earlier keyframe would have left iSAM2's tree by the time it is added.

        The caller then keeps every keyframe (``hold = 0``, no window). Holding just the
        keyframes such loops refer to was measured slower than no window on every graph with
        them (2-core machine, load 2-3): ``w10000.graph`` iSAM2 345 s against 219 s (QR; 59 s
        against 52 s with Cholesky), ``w20000.txt`` over 400 s against 281 s (QR: Cholesky
        meets an indeterminate system there). Their loop closures reach back thousands of
        keyframes, so the hold kept most of the run in the tree and released it a few
        keyframes at a time, each release re-eliminating the whole held tree (up to 18.8 s
        for one update), and the keyframes that left handed their loop closures to a
        marginal factor on the keyframes that stayed.
        """
        return any(lp.later - min(lp.i, lp.j) >= KEEP for lp in loops)

    def _cut(self, i: int) -> int:
        """The first keyframe that stays after the update of keyframe ``i``."""
        cut = i + 1 - KEEP
        return cut if self.hold is None else min(cut, self.hold)

    def due(self, i: int) -> bool:
        """Whether the update of keyframe ``i`` marginalises the oldest ``EVERY`` keyframes."""
        return self._cut(i) - self.first >= EVERY

    def add(self, graph, values) -> None:
        """Record the next keyframe's factors and new values (given to iSAM2 in this step)."""
        gtsam = self.gtsam
        self.graph.push_back(graph)
        leaving = (ord("x"), ord("b"))
        self._added.append([k for k in values.keys() if gtsam.Symbol(k).chr() in leaving])

    def update(self, isam, i: int, graph, values, no_relin) -> None:
        """Keyframe ``i``'s ``isam.update`` with the new ``graph`` and ``values``: when it is
        :meth:`due`, with :meth:`update_params` and then :meth:`marginalise` (the oldest
        keyframes leave iSAM2's tree); otherwise a plain update (``no_relin``: keys kept at
        their linearisation point)."""
        if self.due(i):
            isam.update(graph, values, self.update_params(isam, i, graph, values, no_relin))
            self.marginalise(isam, i)
        else:
            isam.update(graph, values, noRelinKeys=no_relin)

    def update_params(self, isam, i: int, graph, values, no_relin):
        """``ISAM2UpdateParams`` of keyframe ``i``'s update when it is :meth:`due`.

        The whole tree is re-eliminated (``extraReelimKeys``) with the leaving keys first,
        the keys of the new factors last (where iSAM2 puts them by default, so that the
        newest pose stays in the root clique) and everything else between.
        """
        gtsam = self.gtsam
        leaving = {k for j in range(self.first, self._cut(i)) for k in self._added[j]}
        last = set(graph.keyVector()) | set(values.keys())
        groups, reelim = gtsam.KeyGroupMap(), gtsam.KeyList()
        for k in isam.getLinearizationPoint().keys():
            reelim.push_back(k)
            groups.insert2(k, 0 if k in leaving else 2 if k in last else 1)
        for k in values.keys():
            groups.insert2(k, 2)
        params = gtsam.ISAM2UpdateParams()
        params.constrainedKeys = groups
        params.extraReelimKeys = reelim
        params.noRelinKeys = no_relin
        return params

    def marginalise(self, isam, i: int) -> None:
        """After the :meth:`due` update of keyframe ``i``: take the leaving keys' estimates,
        then marginalise them out of ``isam``.

        Raises
        ------
        RuntimeError
            If iSAM2 removed other variables than the leaving ones (it then is inconsistent;
            the caller reports it like any failed update).
        """
        gtsam = self.gtsam
        cut = self._cut(i)
        leaving = [k for j in range(self.first, cut) for k in self._added[j]]
        est = isam.calculateEstimate()
        keys = gtsam.KeyList()
        for k in leaving:
            pose = gtsam.Symbol(k).chr() == ord("x")
            self._taken.insert(k, est.atPose2(k) if pose else est.atPoint2(k))
            keys.push_back(k)
        before = est.size()
        isam.marginalizeLeaves(keys)
        after = isam.getLinearizationPoint().size()
        if after != before - len(leaving):
            raise RuntimeError(
                f"marginalising keyframes {self.first}-{cut - 1} removed {before - after} "
                f"variables instead of {len(leaving)}"
            )
        self.marginalised += cut - self.first
        self.first = cut

    def pose(self, isam, key: int):
        """The estimate of pose ``key`` (``gtsam.Pose2``): iSAM2's, or the one it had when it
        was marginalised."""
        if self._taken.exists(key):
            return self._taken.atPose2(key)
        return isam.calculateEstimatePose2(key)

    def estimate(self, isam):
        """``gtsam.Values`` of every variable of the run: iSAM2's current estimate and the
        marginalised keys at their estimate when they left."""
        out = self.gtsam.Values(self._taken)
        out.insert(isam.calculateEstimate())
        return out
