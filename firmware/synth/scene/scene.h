/* scene.h - synthetic 4D scenes with exact ground truth (the MetaHuman4D role):
 * an articulated, textured 1.6-1.9 m human figure made of 3D Gaussians on a
 * checkered floor, animated analytically, so that every Gaussian has an exact
 * position at ANY real time t, and therefore exact backward / forward motion,
 * depth and 2D flow. Library f4d_scene (depends on f4d_splat only).
 *
 *     scene *s;
 *     scene_new(SCENE_WALK, 7, 0, &s, &err);          // 0 = default density
 *     struct splat_frame f = {0};
 *     struct splat_rig rig;
 *     scene_default_rig(s, 4, 518, 518, &rig);       // 4 cameras, 45 deg apart
 *     scene_eval(s, 1.5 / SCENE_FPS, 1.0 / SCENE_FPS, &f, &err);  // t = frame 1.5
 *     splat_render(r, &rig.cams[0], &f, scene_background(), &out);
 *
 * Units and axes: metres, world z up, the floor is z = 0, the figure stands
 * near the origin facing +y at t = 0. Time t is in seconds; f4d-scene writes
 * steps at t = k / SCENE_FPS. Gaussians keep their index for the whole
 * sequence (index i of every frame is the same surface point).
 *
 * Presets: walk (circle of radius 0.8 m), jump, wave (arm wave and a slow
 * turn), throw (a ball thrown from hand to hand and caught), and the hard
 * ones: fast (spinning run: large displacement per frame), cross (an arm
 * crossing the torso: self-occlusion), exit (the ball is thrown out of every
 * view and comes back), close (one camera 0.45 m from the chest).
 */
#ifndef F4D_SCENE_H
#define F4D_SCENE_H

#include "splat.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Stored in scene.json: never renumbered. */
enum scene_preset {
    SCENE_WALK  = 0,
    SCENE_JUMP  = 1,
    SCENE_WAVE  = 2,
    SCENE_THROW = 3,
    SCENE_FAST  = 4,
    SCENE_CROSS = 5,
    SCENE_EXIT  = 6,
    SCENE_CLOSE = 7,
    SCENE_PRESET_COUNT
};

#define SCENE_FPS 30.0 /* f4d-scene's step rate: key interval 1/30 s */

typedef struct scene scene;

/* Builds the figure. The seed picks the height (1.6-1.9 m), colours and the
 * sampling jitter. gaussians = 0 gives the default density (about 40k);
 * otherwise the figure and floor are resampled to about that many. */
int          scene_new      (enum scene_preset preset, uint64_t seed, size_t gaussians,
                             scene **out, struct f4d_err *err);

/* The same with the knobs a venue varies (tools/f4d-scene venue): zero fields
 * keep scene_new's behaviour, so scene_new(p, s, g) == scene_new_desc of
 * { p, s, g } with everything else 0. The placement (offset, yaw) applies to
 * the figure and its ball, never to the floor. */
struct scene_desc {
    enum scene_preset preset;
    uint64_t seed;
    size_t   gaussians;  /* 0 = default density                              */
    int      no_floor;   /* 1: the figure only (the caller adds a floor)       */
    float    offset[2];  /* figure moved by (x, y) metres on the floor        */
    float    yaw;        /* figure turned about z (radians) around its origin  */
    float    speed;      /* motion time scale, pose(t) = preset(speed * t); 0 = 1 */
    float    girth;      /* body width / depth scale (0 = 1): 0.8 slim .. 1.3 broad */
};
int          scene_new_desc (const struct scene_desc *d, scene **out, struct f4d_err *err);
void         scene_free     (scene *s);
size_t       scene_count    (const scene *s);   /* Gaussians per frame, constant */
/* Gaussians 0 .. scene_figure_count-1 are the figure (and the ball), the rest
 * the static floor: ground truth for what is foreground. */
size_t       scene_figure_count(const scene *s);
float        scene_height   (const scene *s);   /* figure height, metres */
enum scene_preset scene_preset_of(const scene *s);

/* The Gaussians at time t (seconds) into f (resized to scene_count). When
 * dt > 0, f also gets motion_bwd = pos(t - dt) - pos(t) and
 * motion_fwd = pos(t + dt) - pos(t); with dt = 0 motion arrays are left as
 * they are. */
int          scene_eval     (const scene *s, double t, double dt, struct splat_frame *f,
                             struct f4d_err *err);
/* Exact positions only ([3 * count]), cheaper than scene_eval. */
void         scene_positions(const scene *s, double t, float *pos);

/* `views` cameras (1..8, the default rig has 4) on an arc 45 degrees apart
 * centred on the figure's front, 3 m from the subject, 1.3 m high, 60 degree
 * vertical field of view, looking at the figure's middle; named cam0, cam1...
 * Preset close moves the last camera to 0.45 m in front of the chest. */
#define SCENE_VIEWS_DEFAULT 4
void         scene_default_rig(const scene *s, int views, int width, int height, struct splat_rig *rig);
/* Sky colour the scenes are rendered over (3 floats). */
const float *scene_background(void);

const char  *scene_preset_name(enum scene_preset p);
/* Preset by name; -1 (with a message listing the names) when unknown. */
int          scene_preset_from_name(const char *name, struct f4d_err *err);

#ifdef __cplusplus
}
#endif
#endif /* F4D_SCENE_H */
