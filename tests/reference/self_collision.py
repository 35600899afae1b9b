"""Independent reference: Pinocchio with coal checks the rows of written excitation CSVs for self-collision with the
URDF's collision geometry. Pairs of bodies on one joint, and pairs already in contact at the first row (the start
pose), are left out, as the design leaves them out. Prints JSON: {"pairs": N, "colliding": [samples per CSV],
"first": [pair names or null per CSV]}. argv: URDF path, CSV paths."""
import json
import sys

import numpy as np
import pinocchio as pin


def main() -> None:
    urdf, csvs = sys.argv[1], sys.argv[2:]
    model, geom, _ = pin.buildModelsFromUrdf(urdf)
    data = model.createData()

    def adjacent(a: int, b: int) -> bool:
        return a == b or model.parents[a] == b or model.parents[b] == a

    objects = geom.geometryObjects
    candidates = [
        (i, j)
        for i in range(len(objects))
        for j in range(i + 1, len(objects))
        if not adjacent(objects[i].parentJoint, objects[j].parentJoint)
    ]

    def colliding(q, pairs):
        geom.removeAllCollisionPairs()
        for i, j in pairs:
            geom.addCollisionPair(pin.CollisionPair(i, j))
        gdata = pin.GeometryData(geom)
        pin.computeCollisions(model, data, geom, gdata, q, False)
        return [pairs[k] for k, r in enumerate(gdata.collisionResults) if r.isCollision()]

    rows = [np.loadtxt(path, delimiter=",", skiprows=1) for path in csvs]
    nq = model.nq
    at_start = colliding(rows[0][0][1 : 1 + nq], candidates)
    kept = [p for p in candidates if p not in at_start]
    counts, first = [], []
    for table in rows:
        hits = [colliding(r[1 : 1 + nq], kept) for r in table]
        counts.append(sum(1 for h in hits if h))
        named = next((h[0] for h in hits if h), None)
        first.append(None if named is None else [objects[named[0]].name, objects[named[1]].name])
    json.dump({"pairs": len(kept), "colliding": counts, "first": first}, sys.stdout)


if __name__ == "__main__":
    main()
