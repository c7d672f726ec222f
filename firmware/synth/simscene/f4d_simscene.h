/* f4d_simscene.h: the seam between the simulated cameras (hal/sim) and the
 * synthetic 4D scenes (firmware/synth/scene): a hal_sim_render_fn that renders the
 * scene's Gaussians at the trigger time through each camera of the scene's
 * default rig (firmware/gaussians/splat rasterizer), so a simulated take shows a moving
 * human figure instead of the procedural pattern.
 *
 *     struct f4d_simscene *ss;
 *     if (f4d_simscene_new(&ss, "walk", board.sim.seed, board.n_cams, 518, 518, err, n) == 0)
 *         hal_sim_set_renderer(hal_rig_session(&rig, "sim"), f4d_simscene_render, ss);
 *     ...
 *     f4d_simscene_free(ss);
 *
 * Boards select it with "sim": {"scene": "<preset>"} (walk, jump, wave, throw,
 * fast, cross, exit, close); "pattern" keeps the procedural pattern. Rendering
 * costs tens of milliseconds per view on a CPU, so scene boards use the
 * simulated clock ("realtime": false): timing semantics stay exact, the take
 * just records slower than real time.
 */
#ifndef F4D_SIMSCENE_H
#define F4D_SIMSCENE_H

#include <stddef.h>
#include <stdint.h>

#include "hal.h"

struct f4d_simscene;

/* views: cameras of the rig (1..8); width/height: every view's size. */
int f4d_simscene_new(struct f4d_simscene **out, const char *preset, uint64_t seed, uint32_t views,
                     uint32_t width, uint32_t height, struct f4d_err *err);
/* A hal_sim_render_fn: user is the f4d_simscene. */
int f4d_simscene_render(void *user, uint32_t cam, uint64_t t_ns, const struct hal_format *f,
                        uint8_t *dst);
void f4d_simscene_free(struct f4d_simscene *ss);

#endif
