"""``nuav2 infos --executor ray``: Ray actors, each holding one database's tables, make a scene's
info records; the driver streams them into the .pkl in split order (same bytes as one process)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from nuav2.executors.ray_tasks import connected


class SceneInfoActor:
    """A :class:`nuav2.maptr.infos.SceneInfoMaker` as a Ray actor (loads the tables once)."""

    def __init__(self, maker_args: tuple) -> None:
        from nuav2.maptr.infos import SceneInfoMaker

        self.maker = SceneInfoMaker(*maker_args)

    def scene(self, name: str) -> tuple[bytes, int, list]:
        return self.maker.scene(name)


@contextlib.contextmanager
def ray_scene_runner(maker_args: tuple, workers: int, address: str | None) -> Iterator:
    """Yield ``(names, progress) -> iterator of scene results in order`` over ``workers`` actors
    (on a local instance: ``workers`` CPUs; on a cluster, 0 or 1: one actor per cluster CPU)."""
    with connected(address, num_cpus=max(1, workers)) as ray:
        from ray.util import ActorPool

        n = workers if workers > 1 else max(1, int(ray.cluster_resources().get("CPU", 1)))
        actor = ray.remote(num_cpus=1)(SceneInfoActor)
        actors = [actor.remote(maker_args) for _ in range(n)]

        def run(names: list[str], bar) -> Iterator:
            # ActorPool.map hands a scene to an idle actor and yields in order: at most n in flight.
            for out in ActorPool(actors).map(lambda a, name: a.scene.remote(name), names):
                bar.update(finished=1, running=min(n, len(names) - bar.done - 1))
                yield out

        try:
            yield run
        finally:
            for a in actors:
                ray.kill(a)
