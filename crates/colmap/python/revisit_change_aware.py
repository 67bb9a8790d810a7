"""Change-aware joint mapping: cross-visit matches on structure that changed between visits are
found and left out, and the visits are solved jointly on the rest.

A reef changes between visits: corals grow, break and move. A cross-visit match on a coral that
grew is a correct match of two different shapes, and the joint solution, which makes every
track one rigid point, bends whole visits to fit them (on a strongly changed reef with a year of
growth, one visit turned by 19 degrees and scaled by 15%). No per-track residual of that bent
solution shows it: it fits them all.

What a visit saw of itself did not change during the visit. So:
1. each visit is mapped alone (its own images and matches: rigid, its shape right);
2. visits are placed one after another (in their stored order, the first is the reference) by
   the similarity most places agree with: RANSAC over triples of matches with a point in both
   visits, scored by reprojection error in both visits' images (4 px, COLMAP's), one agreeing
   match counted per coral-sized cell of the scene (a grown coral is one piece of evidence,
   however many matches and image pairs hold it; unchanged structure is evidence all over the
   overlap), the best hypotheses refined by robust least squares on their agreeing matches;
   with navigation, only placements whose scale and rotation agree with it;
3. the joint solve: the visits at their placements, every match of the store triangulated by
   COLMAP (a track keeps only the observations within its reprojection threshold, so matches
   on structure that changed, which disagree with the placement, are left out), then bundle
   adjustment over every track, within and across visits, in rounds that each filter the
   observations still over 2 px off (a match on changed structure that the 4 px of the
   placement let in).
Visits that could not be mapped alone or placed join afterwards as COLMAP's incremental mapper
lets them. The result is one joint solution over every correspondence that holds; nothing is
aligned afterwards. Images that no visit could map alone are left out.
"""

import sqlite3
import time

# A cross-visit match whose two visits' points, at the visits' placement, disagree by more than
# this (mean reprojection error over both images, pixels) saw structure that changed.
CHANGED_MATCH_PX = 4.0
# Fewest agreeing matches with which a visit is placed (COLMAP's fewest inliers of a pair).
MIN_PLACING_MATCHES = 15
# A placement's support counts at most this many agreeing matches per cell of the earlier
# visit's frame, a cube SUPPORT_CELL_OF_DEPTH of that visit's median depth a side (20 cm at 2 m
# altitude). A coral that grew is matched consistently, by every image pair that sees it, to a
# similarity of its own (scaled about its base), so it must count as one place however many
# matches and pairs hold it; the site's unchanged structure (rocks, pebbles) agrees all over
# the overlap. On a 2 x 10 reef with a year of growth (strong change, seed 3), capped at 5
# matches per image pair, the placement 8% off in scale and 3.8 degrees in rotation outscored
# the truth (59 to 44) and the joint model came out 15 px off; counted by cells, the truth
# scores 36 against that placement's 31, and the model is 3.9 px off.
SUPPORT_CELL_OF_DEPTH = 0.1
SUPPORT_PER_CELL = 1
# With navigation, a placement must agree with the visits' navigation in scale and rotation
# within this many standard deviations of what the navigation knows of them (a visit's
# cameras fitted to its positions: the fit's residual against the track's spread), and never
# closer than the floors (drift over a small visit is a few percent of its size: 3% of the
# scale on a 3 x 16 reef with a 1% INS drift).
NAVIGATION_SIGMAS = 3.0
NAVIGATION_MIN_SCALE_TOLERANCE = 0.01
NAVIGATION_MIN_ROTATION_TOLERANCE_DEG = 1.0
# After the first adjustment, observations further than this (pixels) from their point are
# filtered and the model adjusted again, for at most this many rounds. Measured on four surveys
# (the README's change-aware figures): 2 px places the visits better than COLMAP's 4 px on each.
FILTER_MAX_REPROJ_ERROR_PX = 2.0
FILTER_ROUNDS = 3
# RANSAC samples drawn per visit pair when placing a visit. Where the cross-visit matches are
# mostly on changed structure (10-20% agree with the truth under a year of growth), a triple of
# right matches is rare: with cells and 600 samples the 2 x 10 reef above (raw learned input)
# came out 5.23 px and the 3 x 16 seed-1 growth reef 3.21 px; with 3000, 2.36 and 2.19 px, and
# better than the per-pair rule on nine of the ten stores of the README's table (the tenth,
# the demo survey without growth, 0.66 -> 0.71 px).
PLACING_SAMPLES = 3000
# A visit pair's matches beyond this many are placed on an evenly drawn share of this size (the
# strong-change and storm surveys measured hold fewer: 0.5k-4.6k).
MAX_PLACING_MATCHES = 5000
# Robust least squares of a placement: the soft-L1 loss's scale, pixels.
REFINE_SCALE_PX = 1.5
REFINE_ROUNDS = 4
# The best hypotheses refined before one is chosen (local optimisation: a sample of three noisy
# matches is rarely the consensus itself, only near it).
REFINED_HYPOTHESES = 8
# A match where the visit has no point of its own takes its depth from the visit's own points
# within this radius (pixels), when there are at least this many.
DEPTH_RADIUS_PX = 24.0
MIN_DEPTH_NEIGHBOURS = 3

PAIR_ID_BASE = 2147483647


def log(message):
    import sys

    print(f"change-aware: {message}", file=sys.stderr, flush=True)


def visit_of_name(name):
    return name.split("/", 1)[0]


def umeyama(src, dst):
    """The similarity (scale, rotation, translation) taking points src onto dst, least squares."""
    import numpy as np

    mean_src, mean_dst = src.mean(0), dst.mean(0)
    a, b = src - mean_src, dst - mean_dst
    u, singular, vt = np.linalg.svd(b.T @ a / len(src))
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    rotation = u @ d @ vt
    scale = np.trace(np.diag(singular) @ d) / (a ** 2).sum(1).mean()
    return scale, rotation, mean_dst - scale * rotation @ mean_src


def compose(first, second):
    """first o second, similarities as (scale, rotation, translation)."""
    a, r, t = first
    b, q, u = second
    return a * b, r @ q, a * r @ u + t


def inverse(similarity):
    a, r, t = similarity
    return 1.0 / a, r.T, -r.T @ t / a


def visit_order(database):
    """The visits in their stored order (Revisit's `revisit_sessions`), else by name."""
    with sqlite3.connect(f"file:{database}?mode=ro", uri=True) as db:
        names = [row[0] for row in db.execute("SELECT name FROM images")]
        try:
            stored = [row[0] for row in db.execute("SELECT name FROM revisit_sessions ORDER BY visit")]
        except sqlite3.OperationalError:
            stored = []
    present = {visit_of_name(n) for n in names}
    return [v for v in stored if v in present] + sorted(present - set(stored))


def map_visits(database, image_path, options, visits, scratch):
    """Each visit mapped alone: its largest model, by visit (visits COLMAP could not map left out)."""
    import pycolmap

    with sqlite3.connect(f"file:{database}?mode=ro", uri=True) as db:
        names = [row[0] for row in db.execute("SELECT name FROM images")]
    models = {}
    for k, visit in enumerate(visits):
        options.image_names = [n for n in names if visit_of_name(n) == visit]
        folder = scratch / f"visit-{k}"
        folder.mkdir(parents=True)
        produced = pycolmap.incremental_mapping(database, image_path, folder, options)
        if produced:
            models[visit] = max(produced.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
            log(f"{visit} alone: {models[visit].num_reg_images()} of {len(options.image_names)} images")
    options.image_names = []
    return models


class VisitGeometry:
    """One visit's own model, asked about its keypoints: the observation's ray and the point the
    visit puts there (its own 3D point, else its own points' depth around the keypoint)."""

    def __init__(self, model):
        import numpy as np

        self.model = model
        self.poses, self.depths = {}, {}
        for image_id, image in model.images.items():
            if not image.has_pose:
                continue
            pose = image.cam_from_world()
            rotation, translation = np.asarray(pose.rotation.matrix()), np.asarray(pose.translation)
            self.poses[image_id] = (rotation, translation)
            rows = [(p.xy, (rotation @ model.points3D[p.point3D_id].xyz + translation)[2])
                    for p in image.points2D if p.has_point3D()]
            if rows:
                self.depths[image_id] = (np.array([r[0] for r in rows]), np.array([r[1] for r in rows]))

    def has(self, image_id):
        return image_id in self.poses

    def observation(self, image_id, index):
        """(rotation, translation, normalized point, focal length in pixels)."""
        image = self.model.images[image_id]
        camera = self.model.cameras[image.camera_id]
        rotation, translation = self.poses[image_id]
        return rotation, translation, camera.cam_from_img(image.points2D[index].xy), camera.mean_focal_length()

    def point(self, image_id, index):
        """The visit's 3D point at this keypoint, None where it has none and no depth around."""
        import numpy as np

        keypoint = self.model.images[image_id].points2D[index]
        if keypoint.has_point3D():
            return self.model.points3D[keypoint.point3D_id].xyz
        if image_id not in self.depths:
            return None
        pixels, depths = self.depths[image_id]
        near = np.sum((pixels - keypoint.xy) ** 2, axis=1) < DEPTH_RADIUS_PX ** 2
        if near.sum() < MIN_DEPTH_NEIGHBOURS:
            return None
        rotation, translation, xy, _ = self.observation(image_id, index)
        return rotation.T @ (np.r_[xy, 1.0] * float(np.median(depths[near])) - translation)


def cell_keys(points, side):
    """One integer per point naming the cube of `side` it lies in (21 bits an axis)."""
    import numpy as np

    cells = np.floor(points / side).astype(np.int64) & 0x1FFFFF
    return (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]


# The reprojection error (pixels) given a point that lands behind a camera.
BEHIND_PX = 1e6


class PairMatches:
    """The cross-visit matches between an earlier visit a and a later visit b, each with both
    visits' points (NaN where a visit has none) and both observations."""

    def __init__(self, keys, points_a, points_b, obs_a, obs_b):
        import numpy as np

        self.keys = keys
        self.points_a, self.points_b = np.array(points_a), np.array(points_b)
        self.obs_a = [np.array([o[j] for o in obs_a]) for j in range(4)]
        self.obs_b = [np.array([o[j] for o in obs_b]) for j in range(4)]
        self.known_a = ~np.isnan(self.points_a[:, 0])
        self.known_b = ~np.isnan(self.points_b[:, 0])
        self.both = np.flatnonzero(self.known_a & self.known_b)
        # The side of a support cell, in a's units: a fraction of its median depth.
        rotations, translations = self.obs_a[0], self.obs_a[1]
        depths = np.einsum("nij,nj->ni", rotations, np.nan_to_num(self.points_a))[:, 2] + translations[:, 2]
        median_depth = float(np.median(depths[self.known_a])) if self.known_a.any() else 1.0
        self.cell = SUPPORT_CELL_OF_DEPTH * median_depth

    def __len__(self):
        return len(self.keys)

    def subset(self, rows):
        """These matches at `rows` (sorted indices) only, on the same support cells."""
        import copy

        import numpy as np

        part = copy.copy(self)
        part.keys = [self.keys[i] for i in rows]
        part.points_a, part.points_b = self.points_a[rows], self.points_b[rows]
        part.obs_a, part.obs_b = [o[rows] for o in self.obs_a], [o[rows] for o in self.obs_b]
        part.known_a, part.known_b = self.known_a[rows], self.known_b[rows]
        part.both = np.flatnonzero(part.known_a & part.known_b)
        return part

    def errors(self, b_to_a, selected):
        """Per direction (b's points in a's images, a's points in b's), the indices of the
        selected matches with a point on the source side and their 2D reprojection errors
        (pixels; BEHIND_PX for a point behind the camera) under the similarity b -> a."""
        import numpy as np

        s, r, t = b_to_a
        for points, obs, known, forward in ((self.points_b, self.obs_a, self.known_b, True),
                                            (self.points_a, self.obs_b, self.known_a, False)):
            keep = np.flatnonzero(selected & known)
            moved = s * points[keep] @ r.T + t if forward else (points[keep] - t) @ r / s
            rotations, translations, xy, focal = (o[keep] for o in obs)
            cam = np.einsum("nij,nj->ni", rotations, moved) + translations
            behind = cam[:, 2] <= 1e-9
            error = (cam[:, :2] / np.where(behind, 1.0, cam[:, 2])[:, None] - xy) * focal[:, None]
            error[behind] = BEHIND_PX
            yield keep, error

    def residuals(self, b_to_a):
        """Per match, the mean reprojection error (pixels) of b's point in a's image and of a's
        point in b's image under the similarity b -> a; inf where neither has a point."""
        import numpy as np

        total, count = np.zeros(len(self)), np.zeros(len(self))
        for keep, error in self.errors(b_to_a, np.ones(len(self), dtype=bool)):
            total[keep] += np.linalg.norm(error, axis=1)
            count[keep] += 1
        return np.where(count > 0, total / np.maximum(count, 1), np.inf)

    def support(self, b_to_a):
        """The agreeing matches under the similarity b -> a, at most SUPPORT_PER_CELL counted
        per cell of a's frame (where a has no point, b's moved by the similarity)."""
        import numpy as np

        agree = self.residuals(b_to_a) < CHANGED_MATCH_PX
        if not agree.any():
            return 0
        s, r, t = b_to_a
        known_a = self.known_a[agree, None]
        where = np.where(known_a, self.points_a[agree], s * np.nan_to_num(self.points_b[agree]) @ r.T + t)
        _, counts = np.unique(cell_keys(where, self.cell), return_counts=True)
        return int(np.minimum(counts, SUPPORT_PER_CELL).sum())


def cross_matches(database, geometry):
    """The verified cross-visit matches between visits mapped alone, by (earlier, later) visit;
    every cross-visit pair's inlier matches by pair id; each image's visit by image id."""
    import numpy as np

    with sqlite3.connect(f"file:{database}?mode=ro", uri=True) as db:
        visit = {i: visit_of_name(n) for i, n in db.execute("SELECT image_id, name FROM images")}
        stored = db.execute("SELECT pair_id, rows, cols, data FROM two_view_geometries WHERE rows > 0").fetchall()
    order = {v: k for k, v in enumerate(geometry)}
    pairs, inliers = {}, {}
    for pair_id, rows, cols, data in stored:
        id2 = pair_id % PAIR_ID_BASE
        id1 = (pair_id - id2) // PAIR_ID_BASE
        if visit[id1] == visit[id2]:
            continue
        matches = np.frombuffer(data, dtype=np.uint32).reshape(rows, cols)
        inliers[pair_id] = matches
        v1, v2 = visit[id1], visit[id2]
        if v1 not in geometry or v2 not in geometry:
            continue
        g1, g2 = geometry[v1], geometry[v2]
        if not (g1.has(id1) and g2.has(id2)):
            continue
        flip = order[v1] > order[v2]
        entry = pairs.setdefault((v2, v1) if flip else (v1, v2), ([], [], [], [], []))
        for k1, k2 in matches.tolist():
            side1 = (g1.point(id1, k1), g1.observation(id1, k1))
            side2 = (g2.point(id2, k2), g2.observation(id2, k2))
            (a, b) = (side2, side1) if flip else (side1, side2)
            entry[0].append((pair_id, k1, k2))
            entry[1].append(a[0] if a[0] is not None else np.full(3, np.nan))
            entry[2].append(b[0] if b[0] is not None else np.full(3, np.nan))
            entry[3].append(a[1])
            entry[4].append(b[1])
    return {key: PairMatches(*entry) for key, entry in pairs.items()}, inliers, visit


def refine(placement, pairs, placed, visit):
    """The placement of `visit` refined on the matches agreeing with it (soft-L1 least squares
    on their reprojection errors), in rounds that re-select the agreeing matches."""
    import numpy as np
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    def unpack(p):
        return np.exp(p[0]), Rotation.from_rotvec(p[1:4]).as_matrix(), p[4:7]

    keys = [(u, visit) for u in placed if (u, visit) in pairs]
    for _ in range(REFINE_ROUNDS):
        selected = {k: pairs[k].residuals(compose(inverse(placed[k[0]]), placement)) < CHANGED_MATCH_PX
                    for k in keys}

        def errors(p):
            moved = unpack(p)
            return np.concatenate([error.ravel() for k in keys
                                   for _, error in pairs[k].errors(compose(inverse(placed[k[0]]), moved), selected[k])])

        start = np.r_[np.log(placement[0]), Rotation.from_matrix(placement[1]).as_rotvec(), placement[2]]
        placement = unpack(least_squares(errors, start, loss="soft_l1", f_scale=REFINE_SCALE_PX).x)
    return placement


def navigation_placements(models, priors, reference):
    """Each visit's similarity into the reference visit's frame by their navigation (each
    visit's cameras fitted to its prior positions), with its relative uncertainty (the two
    fits' residuals against their tracks' spreads), for visits with at least 3 priors."""
    import numpy as np

    onto = {}
    for visit, model in models.items():
        ids = [i for i, image in model.images.items() if image.has_pose and i in priors]
        if len(ids) >= 3:
            centres = np.array([model.images[i].projection_center() for i in ids])
            positions = np.array([priors[i].position for i in ids])
            similarity = umeyama(centres, positions)
            fitted = similarity[0] * centres @ similarity[1].T + similarity[2]
            residual = np.sqrt(np.mean(np.sum((fitted - positions) ** 2, axis=1)))
            spread = np.sqrt(np.mean(np.sum((positions - positions.mean(0)) ** 2, axis=1)))
            onto[visit] = (similarity, residual / max(spread, 1e-9))
    if reference not in onto:
        return {}
    base, base_uncertainty = onto[reference]
    return {visit: (compose(inverse(base), s), float(np.hypot(u, base_uncertainty)))
            for visit, (s, u) in onto.items()}


def agrees_with_navigation(placement, navigation):
    """Whether a placement's scale and rotation lie within what the navigation (a similarity
    and its relative uncertainty, or None) allows."""
    import numpy as np

    if navigation is None:
        return True
    expected, uncertainty = navigation
    turn = placement[1] @ expected[1].T
    angle = np.arccos(np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0))
    scale_tolerance = max(NAVIGATION_SIGMAS * uncertainty, NAVIGATION_MIN_SCALE_TOLERANCE)
    angle_tolerance = max(NAVIGATION_SIGMAS * uncertainty, np.radians(NAVIGATION_MIN_ROTATION_TOLERANCE_DEG))
    return abs(np.log(placement[0] / expected[0])) < scale_tolerance and angle < angle_tolerance


def place_visits(pairs, visits, navigation, seed):
    """Each visit's similarity into the first visit's frame, placed in order against the visits
    placed before it: the hypothesis (RANSAC over any of its pairs, and its navigation's) with
    the most support among its matches with every placed visit, refined; with navigation, only
    hypotheses that agree with it. Visits that cannot be placed are left out."""
    import numpy as np

    rng = np.random.default_rng(seed)
    # Where little changed, two visits share tens of thousands of matches, and every hypothesis
    # is scored against them: an evenly drawn share places the visits alike in a fraction of the
    # time (the unchanged 3 x 16 survey: 155 s of placing on 74k matches).
    drawn = np.random.default_rng(seed + 1)
    pairs = {k: m if len(m) <= MAX_PLACING_MATCHES
             else m.subset(np.sort(drawn.choice(len(m), MAX_PLACING_MATCHES, replace=False)))
             for k, m in pairs.items()}
    placed = {visits[0]: (1.0, np.eye(3), np.zeros(3))}
    for visit in visits[1:]:
        keys = [(u, visit) for u in placed if (u, visit) in pairs]
        if not keys:
            log(f"{visit} not placed: no cross-visit match with a placed visit")
            continue

        def relative(key, placement):
            return compose(inverse(placed[key[0]]), placement)

        def support(placement):
            return sum(pairs[k].support(relative(k, placement)) for k in keys)

        hypotheses = [navigation[visit][0]] if visit in navigation else []
        for key in keys:
            matches = pairs[key]
            for _ in range(PLACING_SAMPLES if len(matches.both) >= 3 else 0):
                sample = rng.choice(matches.both, 3, replace=False)
                b_to_a = umeyama(matches.points_b[sample], matches.points_a[sample])
                if np.isfinite(b_to_a[0]) and b_to_a[0] > 0:
                    hypotheses.append(compose(placed[key[0]], b_to_a))
        scored = sorted(((support(h), k) for k, h in enumerate(hypotheses)
                         if agrees_with_navigation(h, navigation.get(visit))), reverse=True)
        best, best_support = None, -1
        for _, k in scored[:REFINED_HYPOTHESES]:
            placement = refine(hypotheses[k], pairs, placed, visit)
            score = support(placement)
            if score > best_support and agrees_with_navigation(placement, navigation.get(visit)):
                best, best_support = placement, score
        if best is None or best_support < MIN_PLACING_MATCHES:
            log(f"{visit} not placed: the best placement has the support of {max(best_support, 0)} matches")
            continue
        placed[visit] = best
        agreeing = sum(int(np.sum(pairs[k].residuals(relative(k, best)) < CHANGED_MATCH_PX)) for k in keys)
        log(f"{visit} placed: {agreeing} matches agree")
    return placed


def pair_counts(pairs, placed, inliers, visit_of_image, model):
    """Per visit pair sharing verified matches: how many, how many of those between placed
    visits agree with the placement, and how many the joint model holds (both keypoints in one
    track); the rest it dropped."""
    import numpy as np

    counts = {}
    for pair_id, matches in inliers.items():
        id2 = pair_id % PAIR_ID_BASE
        id1 = (pair_id - id2) // PAIR_ID_BASE
        key = tuple(sorted((visit_of_image[id1], visit_of_image[id2])))
        count = counts.setdefault(key, {"matches": 0, "agreeing": 0, "kept": 0, "dropped": 0})
        count["matches"] += len(matches)
        if id1 in model.images and id2 in model.images and model.images[id1].has_pose and model.images[id2].has_pose:
            points1, points2 = model.images[id1].points2D, model.images[id2].points2D
            for k1, k2 in matches.tolist():
                if points1[k1].has_point3D() and points1[k1].point3D_id == points2[k2].point3D_id:
                    count["kept"] += 1
        count["dropped"] = count["matches"] - count["kept"]
    for (a, b), matches in pairs.items():
        if a in placed and b in placed:
            agree = matches.residuals(compose(inverse(placed[a]), placed[b])) < CHANGED_MATCH_PX
            counts[tuple(sorted((a, b)))]["agreeing"] = int(np.sum(agree))
    return {f"{a}-{b}": count for (a, b), count in sorted(counts.items())}


def merged_model(models, placed):
    """One reconstruction holding every placed visit's registered images at their placement
    (no points)."""
    import numpy as np
    import pycolmap

    merged = pycolmap.Reconstruction()
    for visit, model in models.items():
        if visit not in placed:
            continue
        model = pycolmap.Reconstruction(model)
        scale, rotation, translation = placed[visit]
        model.transform(pycolmap.Sim3d(scale, pycolmap.Rotation3d(rotation), translation))
        for camera in model.cameras.values():
            if not merged.exists_camera(camera.camera_id):
                merged.add_camera(camera)
        for rig in model.rigs.values():
            if not merged.exists_rig(rig.rig_id):
                merged.add_rig(rig)
        for frame in model.frames.values():
            if not frame.has_pose:
                continue
            copy = pycolmap.Frame()
            copy.frame_id, copy.rig_id, copy.rig_from_world = frame.frame_id, frame.rig_id, frame.rig_from_world
            for data_id in frame.data_ids:
                copy.add_data_id(data_id)
            merged.add_frame(copy)
        for image in model.images.values():
            if image.has_pose:
                copy = pycolmap.Image(image.name, np.array([p.xy for p in image.points2D]).reshape(-1, 2),
                                      image.camera_id, image.image_id)
                copy.frame_id = image.frame_id
                merged.add_image(copy)
    return merged


def adjustment(model, constant, threads):
    """Bundle adjustment options and configuration over every registered image and point, the
    calibrated cameras (`constant`) held. Threads sum in a varying order: one keeps the result
    repeatable."""
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.ceres.solver_options.num_threads = threads
    config = pycolmap.BundleAdjustmentConfig()
    for image_id, image in model.images.items():
        if image.has_pose:
            config.add_image(image_id)
    for camera_id in model.cameras:
        if camera_id in constant:
            config.set_constant_cam_intrinsics(camera_id)
    return options, config


def adjust(model, constant, threads):
    """One bundle adjustment of the whole model (its gauge fixed by two cameras)."""
    import pycolmap

    options, config = adjustment(model, constant, threads)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    pycolmap.create_default_bundle_adjuster(options, config, model).solve()


def mapper_on(model, database):
    """COLMAP's incremental mapper, begun on `model` with the store's matches."""
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        cache = pycolmap.DatabaseCache.create(db, pycolmap.DatabaseCacheOptions())
    finally:
        db.close()
    mapper = pycolmap.IncrementalMapper(cache)
    mapper.begin_reconstruction(model)
    return mapper


def register_left_out(model, database, options, placed, visit_of_image):
    """Registers, as COLMAP's incremental mapper would (2D-3D RANSAC, then its observations
    triangulated), the images of placed visits that their visit could not map alone. Returns
    how many joined."""
    missing = [i for i, visit in sorted(visit_of_image.items())
               if visit in placed and not (model.exists_image(i) and model.images[i].has_pose)]
    if not missing:
        return 0
    mapper = mapper_on(model, database)
    joined = 0
    for image_id in missing:
        if mapper.register_next_image(options.get_mapper(), image_id):
            mapper.triangulate_image(options.get_triangulation(), image_id)
            joined += 1
    mapper.end_reconstruction(False)
    log(f"{joined} of {len(missing)} images no visit mapped alone joined")
    return joined


def adjust_and_filter(model, database, options):
    """Bundle adjustment rounds over the whole model, each followed by COLMAP's point filter at
    `FILTER_MAX_REPROJ_ERROR_PX` (at most `FILTER_ROUNDS`, until nothing is filtered). The
    triangulation at the placement kept every observation within 4 px of it; once adjusted, an
    observation still a few pixels off is most often a match on structure that changed (a grown
    coral's top), which the plain solve would bend the visits to fit. Tracks are not merged or
    completed again: that would let those matches back in."""
    mapper = mapper_on(model, database)
    mapper_options = options.get_mapper()
    mapper_options.filter_max_reproj_error = FILTER_MAX_REPROJ_ERROR_PX
    filtered = 0
    for _ in range(FILTER_ROUNDS):
        mapper.adjust_global_bundle(mapper_options, options.get_global_bundle_adjustment())
        dropped = mapper.filter_points(mapper_options)
        filtered += dropped
        if dropped == 0:
            break
    mapper.end_reconstruction(False)
    log(f"adjusted: {filtered} observations over {FILTER_MAX_REPROJ_ERROR_PX} px filtered")


def map_jointly(database, image_path, scratch, options, priors, seed, threads, constant):
    """The change-aware joint solve (see the module); `priors` (navigation by image id, may be
    empty) keep placements that disagree with the navigation out. Returns (models as pycolmap's
    incremental_mapping returns them, report), or None when fewer than two visits could be
    placed: the caller then maps the store as it is."""
    import pycolmap

    started = time.monotonic()
    visits = visit_order(database)
    if len(visits) < 2:
        return None
    models = map_visits(database, image_path, options, visits, scratch / "visits")
    mapped = [v for v in visits if v in models]
    geometry = {v: VisitGeometry(models[v]) for v in mapped}
    pairs, inliers, visit_of_image = cross_matches(database, geometry)
    navigation = navigation_placements(models, priors, mapped[0]) if mapped else {}
    placed = place_visits(pairs, mapped, navigation, seed) if mapped else {}
    if len(placed) < 2:
        log("fewer than two visits placed: mapping the store as it is")
        return None
    # Every match triangulated by COLMAP at the placements: a track keeps the observations within
    # its reprojection threshold, so matches on changed structure are left out; then bundle
    # adjustment over every track, within and across visits, and the observations it leaves a few
    # pixels off filtered.
    (scratch / "triangulated").mkdir()
    joint = pycolmap.triangulate_points(merged_model(models, placed), database, image_path,
                                        scratch / "triangulated", clear_points=True, options=options)
    adjust(joint, constant, threads)
    register_left_out(joint, database, options, placed, visit_of_image)
    adjust_and_filter(joint, database, options)
    unplaced = [v for v in visits if v not in placed]
    if unplaced:
        # Visits not placed join as COLMAP's incremental mapper lets them, from the joint model.
        start = scratch / "placed"
        start.mkdir()
        joint.write_binary(str(start))
        (scratch / "continued").mkdir()
        produced = pycolmap.incremental_mapping(database, image_path, scratch / "continued", options,
                                                input_path=str(start))
    else:
        produced = {0: joint}
    largest = max(produced.values(), key=lambda r: r.num_reg_images())
    report = {
        "pairs": pair_counts(pairs, placed, inliers, visit_of_image, largest),
        "placed": sorted(placed),
        "unplaced": unplaced,
        "seconds": time.monotonic() - started,
    }
    return produced, report
