/* scene.c - the synthetic figure: skeleton, surface sampling, textures,
 * analytic poses per preset, forward kinematics and the default rig. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene.h"

#define PI_F 3.14159265358979f

enum bone {
    B_ROOT, B_TORSO, B_HEAD, B_UARM_L, B_FARM_L, B_UARM_R, B_FARM_R,
    B_THIGH_L, B_SHIN_L, B_THIGH_R, B_SHIN_R, B_BALL, B_WORLD, B_COUNT
};
static const int bone_parent[B_COUNT] = { -1, B_ROOT, B_TORSO, B_TORSO, B_UARM_L, B_TORSO, B_UARM_R,
                                          B_ROOT, B_THIGH_L, B_ROOT, B_THIGH_R, -1, -1 };
/* joint offsets in the parent frame, for a 1.78 m figure (scaled by s) */
static const float bone_offset[B_COUNT][3] = {
    { 0, 0, 0 }, { 0, 0, 0.02f }, { 0, 0, 0.55f }, { -0.19f, 0, 0.47f }, { 0, 0, -0.30f },
    { 0.19f, 0, 0.47f }, { 0, 0, -0.30f }, { -0.095f, 0, -0.05f }, { 0, 0, -0.43f },
    { 0.095f, 0, -0.05f }, { 0, 0, -0.43f }, { 0, 0, 0 }, { 0, 0, 0 } };
#define PELVIS_HEIGHT 0.97f

enum tex { T_SKIN, T_HEAD, T_SHIRT, T_SLEEVE, T_FOREARM, T_PANTS, T_SHOE, T_BALL, T_FLOOR };

struct scene {
    enum scene_preset preset;
    float    s;            /* body scale: height / 1.78 */
    float    girth;        /* body x / y scale (scene_desc) */
    float    speed;        /* time scale (scene_desc) */
    float    place_q[4], place_p[3]; /* figure placement (scene_desc) */
    float    ball_radius;
    size_t   n, cap;
    size_t   n_figure;     /* Gaussians 0 .. n_figure-1: figure (and ball) */
    uint8_t *bone;
    float   *local;        /* [3n] position in the bone frame */
    float   *qlocal;       /* [4n] rotation in the bone frame */
    float   *scale;        /* [3n] */
    float   *rgb;          /* [3n] */
    float   *opacity;      /* [n] */
    float    skin[3], shirt[3], stripe[3], pants[3], pants2[3], hair[3];
    uint64_t rng;
};

/* ---- small math -------------------------------------------------------------- */

static void qmul(const float a[4], const float b[4], float o[4])
{
    float r[4] = { a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                   a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                   a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                   a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0] };
    memcpy(o, r, sizeof r);
}

static void qaxis(float ax, float ay, float az, float angle, float q[4])
{
    float h = 0.5f * angle, sn = sinf(h);
    q[0] = cosf(h); q[1] = ax * sn; q[2] = ay * sn; q[3] = az * sn;
}

/* A limb joint: a sideways turn about y, then flexion about x (elbow, hip). */
static void side_then_flex(float side, float flex, float q[4])
{
    float qa[4], qb[4];
    qaxis(0, 1, 0, side, qa);
    qaxis(1, 0, 0, flex, qb);
    qmul(qa, qb, q);
}

static void qrot(const float q[4], const float v[3], float o[3])
{
    float w = q[0], x = q[1], y = q[2], z = q[3];
    float m[9] = { 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                   2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                   2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y) };
    float r[3] = { m[0] * v[0] + m[1] * v[1] + m[2] * v[2], m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
                   m[6] * v[0] + m[7] * v[1] + m[8] * v[2] };
    memcpy(o, r, sizeof r);
}

static double urand(uint64_t *st)
{
    *st ^= *st << 13;
    *st ^= *st >> 7;
    *st ^= *st << 17;
    return (double)(*st >> 11) * (1.0 / 9007199254740992.0);
}

/* ---- poses ---------------------------------------------------------------------- */

struct pose {
    float root[3], yaw, lean, twist, nod;
    float sh_flex[2], sh_abd[2], sh_yaw[2], elbow[2], elbow_side[2]; /* 0 = left, 1 = right */
    float hip_flex[2], hip_abd[2], knee[2];
    float ball[3], ball_spin;
};

struct xform { float q[4], p[3]; };

static void standing(struct pose *P, float s)
{
    memset(P, 0, sizeof *P);
    P->root[2] = PELVIS_HEIGHT * s;
    for (int k = 0; k < 2; k++) {
        P->sh_abd[k] = 0.12f;
        P->elbow[k] = 0.2f;
        P->knee[k] = 0.05f;
        P->hip_flex[k] = 0.02f;
    }
}

static float ease(float u) { return 0.5f - 0.5f * cosf(2.0f * PI_F * u); }

static void base_pose(const scene *S, double t, struct pose *P)
{
    const float s = S->s;
    float tf = (float)t;
    standing(P, s);
    switch (S->preset) {
    case SCENE_WALK:
    case SCENE_FAST: {
        int fast = S->preset == SCENE_FAST;
        float period = fast ? 0.45f : 1.1f, amp = fast ? 0.7f : 0.45f;
        float ph = 2.0f * PI_F * tf / period;
        for (int k = 0; k < 2; k++) {
            float sg = k ? -1.0f : 1.0f, off = k ? PI_F : 0.0f;
            P->hip_flex[k] = sg * amp * sinf(ph);
            P->knee[k] = (fast ? 0.7f : 0.4f) + (fast ? 0.6f : 0.35f) * sinf(ph + off + 1.0f);
            P->sh_flex[k] = -sg * (fast ? 0.9f : 0.35f) * sinf(ph);
            P->elbow[k] = (fast ? 1.2f : 0.35f) + 0.15f * sinf(ph + off);
        }
        P->root[2] = PELVIS_HEIGHT * s - (fast ? 0.08f : 0.03f) * s + 0.02f * s * cosf(2.0f * ph);
        if (fast) {
            P->yaw = 3.0f * tf; /* spinning run on the spot, small circle */
            P->root[0] = 0.25f * sinf(1.5f * tf);
            P->root[1] = 0.25f * cosf(1.5f * tf) - 0.25f;
            P->lean = 0.15f;
        } else {
            const float R = 0.8f, w = 1.0f; /* 0.8 m/s on a circle */
            float th = w * tf;
            P->root[0] = R * sinf(th);
            P->root[1] = -R * cosf(th) + 0.2f;
            P->yaw = th - 0.5f * PI_F;
            P->lean = 0.05f;
        }
        break;
    }
    case SCENE_JUMP: {
        const float period = 1.3f;
        float u = fmodf(tf, period) / period;
        if (u < 0)
            u += 1.0f;
        float c = 0.0f, h = 0.0f, arms = 0.0f;
        if (u < 0.3f) {
            c = sinf(PI_F * u / 0.3f);
            arms = -0.6f * c;
        } else if (u < 0.8f) {
            float v = (u - 0.3f) / 0.5f;
            h = 4.0f * 0.35f * v * (1.0f - v);
            arms = 2.4f * sinf(PI_F * v);
        } else {
            c = 0.5f * sinf(PI_F * (u - 0.8f) / 0.2f);
        }
        P->root[2] = PELVIS_HEIGHT * s - 0.22f * s * c + h;
        for (int k = 0; k < 2; k++) {
            P->hip_flex[k] = 0.9f * c + 0.1f * h;
            P->knee[k] = 1.5f * c + 0.3f * h + 0.05f;
            P->sh_flex[k] = arms;
            P->sh_abd[k] = 0.15f + 0.2f * h;
        }
        P->lean = 0.4f * c;
        break;
    }
    case SCENE_WAVE:
    case SCENE_CLOSE: {
        int close = S->preset == SCENE_CLOSE;
        P->yaw = (close ? 0.3f : 0.6f) * sinf(2.0f * PI_F * tf / 4.0f);
        P->sh_abd[1] = 2.3f;
        P->sh_flex[1] = 0.3f;
        P->elbow[1] = 0.4f;
        P->elbow_side[1] = 0.55f * sinf(2.0f * PI_F * 1.5f * tf);
        P->sh_flex[0] = 0.15f * sinf(2.0f * PI_F * tf / 2.0f);
        P->nod = 0.1f * sinf(2.0f * PI_F * tf / 3.0f);
        P->root[2] += 0.01f * s * sinf(2.0f * PI_F * tf);
        break;
    }
    case SCENE_THROW:
    case SCENE_EXIT: {
        P->yaw = 0.1f * sinf(2.0f * PI_F * tf / 5.0f);
        for (int k = 0; k < 2; k++) {
            P->sh_flex[k] = 0.25f;
            P->sh_abd[k] = 0.25f;
            P->elbow[k] = 1.3f + 0.25f * sinf(2.0f * PI_F * tf + (k ? 0.0f : PI_F));
        }
        break;
    }
    case SCENE_CROSS: {
        float e = ease(tf / 2.0f);
        P->sh_flex[1] = 0.2f + 1.1f * e;
        P->sh_yaw[1] = 1.0f * e;
        P->elbow[1] = 0.3f + 1.2f * e;
        P->yaw = 0.15f * sinf(2.0f * PI_F * tf / 3.0f);
        P->twist = 0.2f * e;
        break;
    }
    default:
        break;
    }
}

static void forward_kinematics(const scene *S, const struct pose *P, struct xform X[B_COUNT])
{
    const float s = S->s;
    float qa[4], qb[4], qc[4];
    for (int b = 0; b < B_COUNT; b++) {
        float q[4] = { 1, 0, 0, 0 };
        switch (b) {
        case B_ROOT:
            qaxis(0, 0, 1, P->yaw, q);
            break;
        case B_TORSO:
            qaxis(0, 0, 1, P->twist, qa);
            qaxis(1, 0, 0, -P->lean, qb);
            qmul(qa, qb, q);
            break;
        case B_HEAD:
            qaxis(1, 0, 0, -P->nod, q);
            break;
        case B_UARM_L:
        case B_UARM_R: {
            int k = b == B_UARM_R, sg = k ? -1 : 1;
            qaxis(0, 0, 1, (float)sg * -P->sh_yaw[k], qa);
            qaxis(0, 1, 0, (float)sg * P->sh_abd[k], qb);
            qmul(qa, qb, qc);
            qaxis(1, 0, 0, P->sh_flex[k], qa);
            qmul(qc, qa, q);
            break;
        }
        case B_FARM_L:
        case B_FARM_R: {
            int k = b == B_FARM_R;
            side_then_flex(k ? -P->elbow_side[k] : P->elbow_side[k], P->elbow[k], q);
            break;
        }
        case B_THIGH_L:
        case B_THIGH_R: {
            int k = b == B_THIGH_R;
            side_then_flex(k ? -P->hip_abd[k] : P->hip_abd[k], P->hip_flex[k], q);
            break;
        }
        case B_SHIN_L:
        case B_SHIN_R:
            qaxis(1, 0, 0, -P->knee[b == B_SHIN_R], q);
            break;
        case B_BALL:
            qaxis(0.6f, 0.0f, 0.8f, P->ball_spin, q);
            break;
        default:
            break;
        }
        int par = bone_parent[b];
        if (par < 0) {
            memcpy(X[b].q, q, sizeof q);
            if (b == B_ROOT)
                memcpy(X[b].p, P->root, sizeof X[b].p);
            else if (b == B_BALL)
                memcpy(X[b].p, P->ball, sizeof X[b].p);
            else
                X[b].p[0] = X[b].p[1] = X[b].p[2] = 0.0f;
        } else {
            float off[3] = { bone_offset[b][0] * s, bone_offset[b][1] * s, bone_offset[b][2] * s }, w[3];
            qrot(X[par].q, off, w);
            for (int k = 0; k < 3; k++)
                X[b].p[k] = X[par].p[k] + w[k];
            qmul(X[par].q, q, X[b].q);
        }
    }
}

/* The hand: 0.30 s below the elbow along the forearm. */
static void hand_position(const scene *S, double t, int right, float out[3])
{
    struct pose P;
    struct xform X[B_COUNT];
    base_pose(S, t, &P);
    forward_kinematics(S, &P, X);
    int b = right ? B_FARM_R : B_FARM_L;
    float v[3] = { 0, 0.02f * S->s, -0.31f * S->s }, w[3];
    qrot(X[b].q, v, w);
    for (int k = 0; k < 3; k++)
        out[k] = X[b].p[k] + w[k];
}

/* Ball: in flight on a parabola between the hand that throws (where it is at
 * the throw) and the hand that catches (where it will be at the catch), in a
 * hand otherwise. Every piece is analytic in t. */
static void ball_pose(const scene *S, double t, struct pose *P)
{
    double period, flight, apex;
    int from, to;
    double u0;
    if (S->preset == SCENE_THROW) {
        period = 2.0; flight = 0.8; apex = 0.8;
        double ph = fmod(t, period);
        if (ph < 0)
            ph += period;
        int second = ph >= 1.0;
        u0 = t - (ph - (second ? 1.0 : 0.0));
        from = second ? 0 : 1;
        to = second ? 1 : 0;
        ph -= second ? 1.0 : 0.0;
        if (ph >= flight) {
            hand_position(S, t, to, P->ball);
            P->ball[2] += S->ball_radius;
            P->ball_spin = (float)(6.0 * (u0 + flight));
            return;
        }
    } else { /* SCENE_EXIT: straight up, out of every view, back into the same hand */
        period = 2.26; flight = 1.76; apex = 3.8;
        double ph = fmod(t, period);
        if (ph < 0)
            ph += period;
        u0 = t - ph;
        from = to = 1;
        if (ph >= flight) {
            hand_position(S, t, 1, P->ball);
            P->ball[2] += S->ball_radius;
            P->ball_spin = (float)(6.0 * (u0 + flight));
            return;
        }
    }
    float a[3], b[3];
    hand_position(S, u0, from, a);
    hand_position(S, u0 + flight, to, b);
    double u = (t - u0) / flight;
    for (int k = 0; k < 3; k++)
        P->ball[k] = (float)((1.0 - u) * a[k] + u * b[k]);
    P->ball[2] += (float)(4.0 * apex * u * (1.0 - u)) + S->ball_radius;
    P->ball_spin = (float)(6.0 * t);
}

static void pose_at(const scene *S, double t, struct xform X[B_COUNT])
{
    struct pose P;
    t *= (double)S->speed;
    base_pose(S, t, &P);
    if (S->preset == SCENE_THROW || S->preset == SCENE_EXIT)
        ball_pose(S, t, &P);
    else
        P.ball[2] = -100.0f; /* no ball in this preset (it has no Gaussians either) */
    forward_kinematics(S, &P, X);
    /* placement: every moving bone (not the floor) turned and moved rigidly */
    for (int b = 0; b < B_COUNT; b++) {
        if (b == B_WORLD)
            continue;
        float w[3];
        qrot(S->place_q, X[b].p, w);
        for (int k = 0; k < 3; k++)
            X[b].p[k] = w[k] + S->place_p[k];
        qmul(S->place_q, X[b].q, X[b].q);
    }
}

/* ---- building the figure ------------------------------------------------------ */

static int push(scene *S, int bone, const float p[3], const float n[3], float st, float sn, const float rgb[3],
                float opacity)
{
    if (S->n == S->cap) {
        size_t c = S->cap ? 2 * S->cap : 4096;
        uint8_t *b = realloc(S->bone, c);
        if (b) S->bone = b;
        float *l = realloc(S->local, 3 * c * sizeof(float));
        if (l) S->local = l;
        float *q = realloc(S->qlocal, 4 * c * sizeof(float));
        if (q) S->qlocal = q;
        float *sc = realloc(S->scale, 3 * c * sizeof(float));
        if (sc) S->scale = sc;
        float *r = realloc(S->rgb, 3 * c * sizeof(float));
        if (r) S->rgb = r;
        float *o = realloc(S->opacity, c * sizeof(float));
        if (o) S->opacity = o;
        if (!b || !l || !q || !sc || !r || !o)
            return -1;
        S->cap = c;
    }
    size_t i = S->n++;
    S->bone[i] = (uint8_t)bone;
    memcpy(S->local + 3 * i, p, 3 * sizeof(float));
    if (bone != B_WORLD && bone != B_BALL) { /* proportions: wider or slimmer, same height */
        S->local[3 * i] *= S->girth;
        S->local[3 * i + 1] *= S->girth;
    }
    /* shortest arc from +z to the normal: the flat axis follows the surface */
    float *q = S->qlocal + 4 * i;
    if (n[2] < -0.9999f) {
        q[0] = 0; q[1] = 1; q[2] = 0; q[3] = 0;
    } else {
        float w = 1.0f + n[2], x = -n[1], y = n[0], z = 0.0f;
        float len = sqrtf(w * w + x * x + y * y + z * z);
        q[0] = w / len; q[1] = x / len; q[2] = y / len; q[3] = z / len;
    }
    S->scale[3 * i] = st;
    S->scale[3 * i + 1] = st;
    S->scale[3 * i + 2] = sn;
    memcpy(S->rgb + 3 * i, rgb, 3 * sizeof(float));
    S->opacity[i] = opacity;
    return 0;
}

static void mix(const float a[3], const float b[3], float t, float o[3])
{
    for (int k = 0; k < 3; k++)
        o[k] = a[k] + (b[k] - a[k]) * t;
}

/* Colour of a surface point: p in the bone frame, c relative to the primitive
 * centre, n the normal. Patterns are there so that motion is observable. */
static void texture(const scene *S, int tex, const float p[3], const float c[3], const float n[3], float o[3])
{
    const float s = S->s;
    static const float dark[3] = { 0.08f, 0.07f, 0.07f }, white[3] = { 0.92f, 0.92f, 0.9f },
                       red[3] = { 0.75f, 0.15f, 0.15f };
    switch (tex) {
    case T_HEAD: {
        float zr = c[2] / s, xr = c[0] / s;
        if (zr > 0.045f || (n[1] < -0.2f && zr > -0.06f))
            memcpy(o, S->hair, 3 * sizeof(float));
        else if (n[1] > 0.5f && fabsf(zr - 0.015f) < 0.014f && fabsf(fabsf(xr) - 0.035f) < 0.014f)
            memcpy(o, dark, 3 * sizeof(float)); /* eyes */
        else if (n[1] > 0.6f && fabsf(zr + 0.055f) < 0.01f && fabsf(xr) < 0.03f)
            memcpy(o, red, 3 * sizeof(float)); /* mouth */
        else
            memcpy(o, S->skin, 3 * sizeof(float));
        break;
    }
    case T_SKIN:
        memcpy(o, S->skin, 3 * sizeof(float));
        break;
    case T_SHIRT: {
        int band = (int)floorf(p[2] / (0.06f * s));
        if (n[1] > 0.6f && fabsf(p[0]) < 0.06f * s && fabsf(p[2] - 0.36f * s) < 0.06f * s)
            memcpy(o, white, 3 * sizeof(float)); /* chest logo: front and back differ */
        else
            memcpy(o, (band & 1) ? S->stripe : S->shirt, 3 * sizeof(float));
        break;
    }
    case T_SLEEVE: {
        int band = (int)floorf(-p[2] / (0.05f * s));
        memcpy(o, (band & 1) ? S->stripe : S->shirt, 3 * sizeof(float));
        break;
    }
    case T_FOREARM: {
        float z = -p[2] / s;
        if (z > 0.22f && z < 0.245f)
            memcpy(o, dark, 3 * sizeof(float)); /* watch band */
        else if (atan2f(p[1], p[0]) > 1.2f)
            mix(S->skin, dark, 0.25f, o); /* one darker side shows the twist */
        else
            memcpy(o, S->skin, 3 * sizeof(float));
        break;
    }
    case T_PANTS: {
        int sector = (int)floorf((atan2f(c[1], c[0]) + PI_F) / (PI_F / 4.0f));
        int band = (int)floorf(-p[2] / (0.07f * s) + 100.0f);
        memcpy(o, ((sector + band) & 1) ? S->pants2 : S->pants, 3 * sizeof(float));
        break;
    }
    case T_SHOE:
        memcpy(o, c[2] < -0.02f * s ? white : dark, 3 * sizeof(float));
        break;
    case T_BALL: {
        float r = S->ball_radius, x = c[0] / r, y = c[1] / r, z = c[2] / r;
        static const float orange[3] = { 0.95f, 0.45f, 0.08f };
        if (fabsf(x) < 0.08f || fabsf(y) < 0.08f || fabsf(z) < 0.08f)
            memcpy(o, dark, 3 * sizeof(float));
        else if (x > 0 && y > 0 && z > 0)
            memcpy(o, white, 3 * sizeof(float));
        else
            memcpy(o, orange, 3 * sizeof(float));
        break;
    }
    default: { /* floor: 0.4 m checker with thin lines */
        int i = (int)floorf(p[0] / 0.4f + 100.0f), j = (int)floorf(p[1] / 0.4f + 100.0f);
        float fx = p[0] / 0.4f - floorf(p[0] / 0.4f), fy = p[1] / 0.4f - floorf(p[1] / 0.4f);
        float v = ((i + j) & 1) ? 0.62f : 0.42f;
        if (fx < 0.04f || fy < 0.04f)
            v = 0.25f;
        o[0] = v; o[1] = v * 0.97f; o[2] = v * 0.9f;
        break;
    }
    }
}

static int add_point(scene *S, int bone, int tex, const float p[3], const float c[3], const float n[3],
                     float sp)
{
    float rgb[3];
    texture(S, tex, p, c, n, rgb);
    float op = 0.9f + 0.09f * (float)urand(&S->rng);
    return push(S, bone, p, n, 0.75f * sp, 0.2f * sp, rgb, op);
}

/* Uniform-area samples of an ellipsoid (rejection from uniform sphere points). */
static int add_ellipsoid(scene *S, int bone, int tex, const float ctr[3], const float r[3], float sp)
{
    float a = r[0], b = r[1], c = r[2];
    const float pw = 1.6075f;
    float area = 4.0f * PI_F * powf((powf(a * b, pw) + powf(a * c, pw) + powf(b * c, pw)) / 3.0f, 1.0f / pw);
    int target = (int)ceilf(area / (sp * sp));
    float smax = fmaxf(b * c, fmaxf(a * c, a * b));
    int got = 0;
    for (int guard = 0; got < target && guard < 50 * target; guard++) {
        float z = (float)(2.0 * urand(&S->rng) - 1.0), ph = (float)(2.0 * PI_F * urand(&S->rng));
        float rr = sqrtf(fmaxf(0.0f, 1.0f - z * z));
        float u[3] = { rr * cosf(ph), rr * sinf(ph), z };
        float st = sqrtf(b * c * u[0] * b * c * u[0] + a * c * u[1] * a * c * u[1] + a * b * u[2] * a * b * u[2]);
        if (urand(&S->rng) * smax > st)
            continue;
        float q[3] = { a * u[0], b * u[1], c * u[2] };
        float p[3] = { ctr[0] + q[0], ctr[1] + q[1], ctr[2] + q[2] };
        float n[3] = { u[0] / a, u[1] / b, u[2] / c };
        float nl = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        n[0] /= nl; n[1] /= nl; n[2] /= nl;
        if (add_point(S, bone, tex, p, q, n, sp) < 0)
            return -1;
        got++;
    }
    return 0;
}

/* A capsule along the bone's -z axis from z = 0 to z = -len. */
static int add_capsule(scene *S, int bone, int tex, float len, float radius, float sp)
{
    int rings = (int)ceilf(len / sp), around = (int)ceilf(2.0f * PI_F * radius / sp);
    for (int i = 0; i <= rings; i++) {
        float z = -len * (float)i / (float)rings;
        for (int j = 0; j < around; j++) {
            float ph = 2.0f * PI_F * ((float)j + 0.5f * (float)(i & 1)) / (float)around;
            float n[3] = { cosf(ph), sinf(ph), 0.0f };
            float c[3] = { radius * n[0], radius * n[1], z + 0.5f * len };
            float p[3] = { radius * n[0], radius * n[1], z };
            if (add_point(S, bone, tex, p, c, n, sp) < 0)
                return -1;
        }
    }
    int caps = (int)ceilf(2.0f * PI_F * radius * radius / (sp * sp));
    for (int end = 0; end < 2; end++)
        for (int i = 0; i < caps; i++) {
            float z = 1.0f - ((float)i + 0.5f) / (float)caps, rr = sqrtf(fmaxf(0.0f, 1.0f - z * z));
            float ph = (float)i * 2.39996323f;
            float n[3] = { rr * cosf(ph), rr * sinf(ph), end ? -z : z };
            float p[3] = { radius * n[0], radius * n[1], radius * n[2] + (end ? -len : 0.0f) };
            float c[3] = { p[0], p[1], p[2] + 0.5f * len };
            if (add_point(S, bone, tex, p, c, n, sp) < 0)
                return -1;
        }
    return 0;
}

static int add_floor(scene *S, float sp)
{
    const float half = 2.6f;
    int n = (int)ceilf(2.0f * half / sp);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            float p[3] = { -half + ((float)i + 0.5f) * sp, -half + ((float)j + 0.5f) * sp + 0.4f, 0.0f };
            float nn[3] = { 0, 0, 1 }, rgb[3];
            texture(S, T_FLOOR, p, p, nn, rgb);
            if (push(S, B_WORLD, p, nn, 0.6f * sp, 0.05f * sp, rgb, 0.98f) < 0)
                return -1;
        }
    return 0;
}

static const float palette_skin[4][3] = { { 0.87f, 0.68f, 0.56f }, { 0.72f, 0.52f, 0.38f },
                                          { 0.52f, 0.36f, 0.25f }, { 0.95f, 0.8f, 0.7f } };
static const float palette_cloth[6][3] = { { 0.15f, 0.35f, 0.75f }, { 0.8f, 0.2f, 0.2f }, { 0.2f, 0.6f, 0.3f },
                                           { 0.85f, 0.75f, 0.2f }, { 0.5f, 0.25f, 0.6f }, { 0.1f, 0.55f, 0.6f } };

static int build(scene *S, float body_sp, float floor_sp)
{
    const float s = S->s, sp = body_sp;
    int rc = 0;
    /* pelvis and torso */
    float pc[3] = { 0, 0, -0.01f * s }, pr[3] = { 0.165f * s, 0.11f * s, 0.12f * s };
    rc |= add_ellipsoid(S, B_ROOT, T_PANTS, pc, pr, sp);
    float tc[3] = { 0, 0, 0.27f * s }, tr[3] = { 0.18f * s, 0.115f * s, 0.27f * s };
    rc |= add_ellipsoid(S, B_TORSO, T_SHIRT, tc, tr, sp);
    float nc[3] = { 0, 0, 0.55f * s }, nr[3] = { 0.05f * s, 0.05f * s, 0.06f * s };
    rc |= add_ellipsoid(S, B_TORSO, T_SKIN, nc, nr, sp);
    float hc[3] = { 0, 0.01f * s, 0.15f * s }, hr[3] = { 0.085f * s, 0.1f * s, 0.115f * s };
    rc |= add_ellipsoid(S, B_HEAD, T_HEAD, hc, hr, sp);
    for (int k = 0; k < 2; k++) {
        rc |= add_capsule(S, k ? B_UARM_R : B_UARM_L, T_SLEEVE, 0.28f * s, 0.047f * s, sp);
        rc |= add_capsule(S, k ? B_FARM_R : B_FARM_L, T_FOREARM, 0.25f * s, 0.036f * s, sp);
        float hnd[3] = { 0, 0.01f * s, -0.3f * s }, hndr[3] = { 0.025f * s, 0.045f * s, 0.06f * s };
        rc |= add_ellipsoid(S, k ? B_FARM_R : B_FARM_L, T_SKIN, hnd, hndr, sp);
        rc |= add_capsule(S, k ? B_THIGH_R : B_THIGH_L, T_PANTS, 0.42f * s, 0.07f * s, sp);
        rc |= add_capsule(S, k ? B_SHIN_R : B_SHIN_L, T_PANTS, 0.40f * s, 0.05f * s, sp);
        float fc[3] = { 0, 0.05f * s, -0.475f * s }, fr[3] = { 0.045f * s, 0.11f * s, 0.04f * s };
        rc |= add_ellipsoid(S, k ? B_SHIN_R : B_SHIN_L, T_SHOE, fc, fr, sp);
    }
    if (S->preset == SCENE_THROW || S->preset == SCENE_EXIT) {
        float bc[3] = { 0, 0, 0 }, br[3] = { S->ball_radius, S->ball_radius, S->ball_radius };
        rc |= add_ellipsoid(S, B_BALL, T_BALL, bc, br, 0.8f * sp);
    }
    S->n_figure = S->n;
    if (floor_sp > 0.0f)
        rc |= add_floor(S, floor_sp);
    return rc;
}

int scene_new(enum scene_preset preset, uint64_t seed, size_t gaussians, scene **out, struct f4d_err *err)
{
    struct scene_desc d = { .preset = preset, .seed = seed, .gaussians = gaussians };
    return scene_new_desc(&d, out, err);
}

int scene_new_desc(const struct scene_desc *d, scene **out, struct f4d_err *err)
{
    if (!d) {
        if (err) snprintf(err->msg, sizeof err->msg, "scene_new: description is NULL");
        return F4D_EINVAL;
    }
    enum scene_preset preset = d->preset;
    uint64_t seed = d->seed;
    size_t gaussians = d->gaussians;
    float girth = d->girth == 0.0f ? 1.0f : d->girth, speed = d->speed == 0.0f ? 1.0f : d->speed;
    if (!(girth >= 0.5f && girth <= 2.0f) || !(speed >= 0.1f && speed <= 5.0f) || !isfinite(d->yaw) ||
        !isfinite(d->offset[0]) || !isfinite(d->offset[1]) || fabsf(d->offset[0]) > 100.0f ||
        fabsf(d->offset[1]) > 100.0f) {
        if (err)
            snprintf(err->msg, sizeof err->msg,
                     "scene_new: girth %g (0.5..2), speed %g (0.1..5), yaw and offset (|x| <= 100 m) must be finite",
                     (double)girth, (double)speed);
        return F4D_EINVAL;
    }
    if (!out) {
        if (err) snprintf(err->msg, sizeof err->msg, "scene_new: out is NULL");
        return F4D_EINVAL;
    }
    *out = NULL;
    if ((int)preset < 0 || preset >= SCENE_PRESET_COUNT) {
        if (err) snprintf(err->msg, sizeof err->msg, "scene_new: unknown preset %d", (int)preset);
        return F4D_EINVAL;
    }
    if (gaussians != 0 && (gaussians < 1000 || gaussians > 20000000)) {
        if (err) snprintf(err->msg, sizeof err->msg, "scene_new: %zu Gaussians requested, need 1000..20000000 (or 0)", gaussians);
        return F4D_EINVAL;
    }
    scene *S = calloc(1, sizeof *S);
    if (!S) {
        if (err) snprintf(err->msg, sizeof err->msg, "scene_new: out of memory");
        return F4D_ENOMEM;
    }
    S->preset = preset;
    S->girth = girth;
    S->speed = speed;
    qaxis(0, 0, 1, d->yaw, S->place_q);
    S->place_p[0] = d->offset[0];
    S->place_p[1] = d->offset[1];
    S->place_p[2] = 0.0f;
    S->rng = seed * 0x9E3779B97F4A7C15ull + 0x1234567ull;
    for (int k = 0; k < 4; k++)
        urand(&S->rng);
    float height = 1.6f + 0.3f * (float)urand(&S->rng);
    S->s = height / 1.78f;
    S->ball_radius = 0.11f;
    memcpy(S->skin, palette_skin[(int)(urand(&S->rng) * 4) & 3], sizeof S->skin);
    int cs = (int)(urand(&S->rng) * 6) % 6, cp = (cs + 1 + (int)(urand(&S->rng) * 5)) % 6;
    memcpy(S->shirt, palette_cloth[cs], sizeof S->shirt);
    mix(S->shirt, (const float[3]){ 1, 1, 1 }, 0.55f, S->stripe);
    memcpy(S->pants, palette_cloth[cp], sizeof S->pants);
    mix(S->pants, (const float[3]){ 0, 0, 0 }, 0.45f, S->pants2);
    static const float hair[3][3] = { { 0.2f, 0.12f, 0.06f }, { 0.05f, 0.04f, 0.04f }, { 0.6f, 0.45f, 0.2f } };
    memcpy(S->hair, hair[(int)(urand(&S->rng) * 3) % 3], sizeof S->hair);
    /* default density: ~0.9 cm on the body, 5 cm on the floor (about 40k in all) */
    float body_sp = 0.009f, floor_sp = 0.05f;
    if (gaussians) {
        /* the default build has ~27.5k body + ~10.8k floor Gaussians */
        float k = sqrtf(38300.0f / (float)gaussians);
        body_sp *= k;
        floor_sp *= k;
    }
    if (build(S, body_sp * S->s, d->no_floor ? 0.0f : floor_sp) < 0) {
        scene_free(S);
        if (err) snprintf(err->msg, sizeof err->msg, "scene_new: out of memory building the figure");
        return F4D_ENOMEM;
    }
    *out = S;
    return F4D_OK;
}

void scene_free(scene *s)
{
    if (!s)
        return;
    free(s->bone); free(s->local); free(s->qlocal); free(s->scale); free(s->rgb); free(s->opacity);
    free(s);
}

size_t scene_count(const scene *s) { return s ? s->n : 0; }
size_t scene_figure_count(const scene *s) { return s ? s->n_figure : 0; }
float scene_height(const scene *s) { return s ? 1.78f * s->s : 0.0f; }
enum scene_preset scene_preset_of(const scene *s) { return s->preset; }

/* Point i where its bone's transform X puts it: p + q * local. */
static void place_point(const scene *S, const struct xform *X, size_t i, float pos[3])
{
    const struct xform *x = &X[S->bone[i]];
    float w[3];
    qrot(x->q, S->local + 3 * i, w);
    for (int k = 0; k < 3; k++)
        pos[k] = x->p[k] + w[k];
}

void scene_positions(const scene *S, double t, float *pos)
{
    struct xform X[B_COUNT];
    pose_at(S, t, X);
    for (size_t i = 0; i < S->n; i++)
        place_point(S, X, i, pos + 3 * i);
}

int scene_eval(const scene *S, double t, double dt, struct splat_frame *f, struct f4d_err *err)
{
    if (!S || !f || !isfinite(t) || !(dt >= 0) || !isfinite(dt)) {
        if (err) snprintf(err->msg, sizeof err->msg, "scene_eval: bad argument (t and dt must be finite, dt >= 0)");
        return F4D_EINVAL;
    }
    int rc = splat_frame_resize(f, S->n, dt > 0, err);
    if (rc < 0)
        return rc;
    struct xform X[B_COUNT];
    pose_at(S, t, X);
    for (size_t i = 0; i < S->n; i++) {
        place_point(S, X, i, f->pos + 3 * i);
        qmul(X[S->bone[i]].q, S->qlocal + 4 * i, f->rot + 4 * i);
    }
    memcpy(f->scale, S->scale, 3 * S->n * sizeof(float));
    memcpy(f->rgb, S->rgb, 3 * S->n * sizeof(float));
    memcpy(f->opacity, S->opacity, S->n * sizeof(float));
    if (dt > 0) {
        scene_positions(S, t - dt, f->motion_bwd);
        scene_positions(S, t + dt, f->motion_fwd);
        for (size_t i = 0; i < 3 * S->n; i++) {
            f->motion_bwd[i] -= f->pos[i];
            f->motion_fwd[i] -= f->pos[i];
        }
    }
    return F4D_OK;
}

void scene_default_rig(const scene *S, int views, int width, int height, struct splat_rig *rig)
{
    memset(rig, 0, sizeof *rig);
    views = views < 1 ? 1 : (views > 8 ? 8 : views);
    rig->count = views;
    const float target[3] = { 0, 0, 0.95f * S->s }, up[3] = { 0, 0, 1 };
    float f = 0.5f * (float)height / tanf(30.0f * PI_F / 180.0f);
    for (int k = 0; k < views; k++) {
        struct splat_camera *c = &rig->cams[k];
        snprintf(c->name, sizeof c->name, "cam%d", k);
        c->width = width; c->height = height;
        c->fx = c->fy = f;
        c->cx = 0.5f * (float)width;
        c->cy = 0.5f * (float)height;
        float a = 45.0f * ((float)k - 0.5f * (float)(views - 1)) * PI_F / 180.0f;
        float eye[3] = { 3.0f * sinf(a), 3.0f * cosf(a), 1.3f };
        splat_camera_look_at(c, eye, target, up);
    }
    if (S->preset == SCENE_CLOSE) {
        /* 0.45 m in front of the chest surface (chest front at y = 0.115 s) */
        float eye[3] = { 0.05f, 0.115f * S->s + 0.45f, 1.3f * S->s };
        float at[3] = { 0.0f, 0.0f, 1.2f * S->s };
        splat_camera_look_at(&rig->cams[views - 1], eye, at, up);
    }
}

const float *scene_background(void)
{
    static const float sky[3] = { 0.55f, 0.65f, 0.78f };
    return sky;
}

static const char *const preset_names[SCENE_PRESET_COUNT] = { "walk", "jump", "wave", "throw",
                                                               "fast", "cross", "exit", "close" };

const char *scene_preset_name(enum scene_preset p)
{
    return ((int)p >= 0 && p < SCENE_PRESET_COUNT) ? preset_names[p] : "unknown";
}

int scene_preset_from_name(const char *name, struct f4d_err *err)
{
    for (int k = 0; k < SCENE_PRESET_COUNT; k++)
        if (name && !strcmp(name, preset_names[k]))
            return k;
    if (err)
        snprintf(err->msg, sizeof err->msg,
                 "unknown preset '%s' (walk, jump, wave, throw, fast, cross, exit, close)", name ? name : "");
    return -1;
}
