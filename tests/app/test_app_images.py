"""The camera image with the labels on it (``GET /api/images/{id}/overlay``) and picking a
segment on it (``GET /api/images/{id}/pick``), on the test drive's run."""

from __future__ import annotations

import cv2
import numpy as np
from fastapi.testclient import TestClient

from app.image_overlay import PICK_RADIUS_PX
from app.scene.colours import GUARDRAIL, OTHER, SELECTED
from app.session import ReviewSession
from guardrail_core.formats.drive import Drive


def _png(response) -> np.ndarray:  # type: ignore[no-untyped-def]
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "image/png"
    return cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]


def _clear_segment(session: ReviewSession) -> tuple[int, int, np.ndarray]:
    """A segment with a crop, its image, and the pixel of its point nearest the camera, where no
    point of another segment within the pick radius is nearer."""
    seg = session.run.segments
    for s in np.flatnonzero((seg["crop_status"] == 0) & (seg["n_points"] >= 20)):
        image = int(seg["image"][s])
        found = session.overlay.points(image)
        mine = np.flatnonzero(found.segment == s)
        if len(mine) == 0:
            continue
        front = mine[np.argmin(found.depth[mine])]
        pixel = found.pixel[front]
        near = ((found.pixel - pixel) ** 2).sum(axis=1) <= (PICK_RADIUS_PX + 2) ** 2
        rivals = near & (found.segment != s) & (found.segment >= 0)
        if not rivals.any():
            return int(s), image, pixel
    raise AssertionError("no segment stands clear on its image")


def test_the_segment_detail_names_its_image(
    module_client: TestClient, module_session: ReviewSession
) -> None:
    s, image, _ = _clear_segment(module_session)
    detail = module_client.get(f"/api/segments/{s}").json()
    assert detail["image_id"] == image
    assert detail["image"] == module_session.run.info.images[image]
    without = int(np.flatnonzero(module_session.run.segments["image"] < 0)[0])
    assert module_client.get(f"/api/segments/{without}").json()["image_id"] is None


def test_every_point_of_the_chosen_image_s_segment_is_drawn(
    module_session: ReviewSession, drive: Drive
) -> None:
    """The chosen image holds all its segment's points (§3.2), so the overlay draws them all."""
    seg = module_session.run.segments
    point_segment = module_session.run.folder.point_segment()
    ok = np.flatnonzero(seg["crop_status"] == 0)
    checked = 0
    for s in ok[:: max(1, len(ok) // 40)]:
        image = int(seg["image"][s])
        position = drive.images[image].T_world_camera[:3, 3]
        points = drive.points.xyz[point_segment == s]
        if (
            np.linalg.norm(points - position, axis=1).max()
            >= module_session.crops.params.max_range_m
        ):
            continue  # a point beyond the crops' range: left out by design
        assert (module_session.overlay.points(image).segment == s).sum() == seg["n_points"][s]
        checked += 1
    assert checked >= 20


def test_the_overlay_colours_points_by_label_and_outlines_the_segment(
    module_client: TestClient, module_session: ReviewSession
) -> None:
    s, image, (x, y) = _clear_segment(module_session)
    width, height = module_session.overlay.size(image)
    plain = _png(module_client.get(f"/api/images/{image}/overlay"))
    outlined = _png(module_client.get(f"/api/images/{image}/overlay", params={"segment": s}))
    assert plain.shape == outlined.shape == (height, width, 3)
    label = GUARDRAIL if module_session.effective_label()[s] else OTHER
    # PNG is lossless: the segment's front point has its label's colour, then the outline's.
    np.testing.assert_array_equal(plain[y, x], label)
    np.testing.assert_array_equal(outlined[y, x], SELECTED)
    drawn = int((module_session.overlay.points(image).segment == s).sum())
    assert (outlined == SELECTED).all(axis=2).sum() > drawn  # its points and its hull
    assert not (plain == SELECTED).all(axis=2).any()
    photo = module_session.drive.read_image(module_session.drive.images[image])
    assert (plain != photo).any(axis=2).mean() > 0.01  # points drawn on the photo


def test_a_click_on_a_point_picks_its_segment(
    module_client: TestClient, module_session: ReviewSession
) -> None:
    s, image, (x, y) = _clear_segment(module_session)
    answer = module_client.get(f"/api/images/{image}/pick", params={"x": x + 1.5, "y": y - 1.5})
    assert answer.status_code == 200 and answer.json() == {"image": image, "segment": s}
    # The pixel farthest from any segment's point picks nothing.
    found = module_session.overlay.points(image)
    width, height = module_session.overlay.size(image)
    free = np.ones((height, width), np.uint8)
    ours = found.segment >= 0
    free[found.pixel[ours, 1], found.pixel[ours, 0]] = 0
    field = cv2.distanceTransform(free, cv2.DIST_L2, 5)
    row, col = np.unravel_index(np.argmax(field), field.shape)
    assert field[row, col] > PICK_RADIUS_PX + 1
    empty = module_client.get(f"/api/images/{image}/pick", params={"x": col, "y": row}).json()
    assert empty == {"image": image, "segment": None}
    # The page sends a radius worth 8 screen pixels at the scale it shows the image: a wider
    # radius reaches the nearest point from there, the default does not.
    exact = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    row, col = np.argwhere((exact > 15) & (exact < 40))[0]
    gap = float(exact[row, col])  # pixels to the nearest segment point
    wide = {"x": int(col), "y": int(row), "radius": gap + 1}
    assert module_client.get(f"/api/images/{image}/pick", params=wide).json()["segment"] is not None
    narrow = {"x": int(col), "y": int(row), "radius": gap - 1}
    assert module_client.get(f"/api/images/{image}/pick", params=narrow).json()["segment"] is None
    assert (
        module_client.get(
            f"/api/images/{image}/pick", params={"x": col, "y": row, "radius": 0}
        ).status_code
        == 422
    )


def test_bad_images_segments_and_pixels_are_refused(
    module_client: TestClient, module_session: ReviewSession
) -> None:
    n = len(module_session.drive.images)
    for url in (
        f"/api/images/{n}/overlay",
        "/api/images/-1/overlay",
        f"/api/images/{n}/pick?x=1&y=1",
    ):
        assert module_client.get(url).status_code == 404, url
    assert (
        module_client.get(f"/api/images/0/overlay?segment={len(module_session.run)}").status_code
        == 404
    )
    width, height = module_session.overlay.size(0)
    for query in (f"x={width}&y=1", f"x=1&y={height}", "x=-1&y=1", "x=a&y=1", "y=1"):
        assert module_client.get(f"/api/images/0/pick?{query}").status_code == 422, query
    assert module_client.get("/api/images/zero/overlay").status_code == 422
