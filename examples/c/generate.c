/* Motion for a WAV file through the LiveGesture C library (docs/c.md).
 *
 *   target/c/generate BUNDLE IN.wav SEED [tract|ort] > poses.f32
 *
 * Writes the SMPL-X axis-angle poses of every frame to stdout as little-endian float32, frames x 165
 * (the `poses` of `livegesture generate IN.wav -o OUT.npz --bundle BUNDLE --seed SEED`, bit for bit).
 * Errors go to stderr with the library's message; exit status 2 for bad input, 1 otherwise. Nothing
 * is written to stdout unless the whole file was generated.
 *
 * Build: scripts/build_c_example.sh (links target/release/liblivegesture_c.a).
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "livegesture.h"

#define BATCH 64 /* frames read per lg_stream_read */

static int fail(const char *what, LgStatus status) {
    fprintf(stderr, "generate: %s: %s\n", what, lg_last_error());
    return status == LG_STATUS_INPUT || status == LG_STATUS_NOT_FOUND ? 2 : 1;
}

int main(int argc, char **argv) {
    if (argc < 4 || argc > 5) {
        fprintf(stderr, "usage: %s BUNDLE IN.wav SEED [tract|ort] > poses.f32\n", argv[0]);
        return 2;
    }
    const char *bundle = argv[1], *wav = argv[2], *backend = argc == 5 ? argv[4] : "tract";
    char *end = NULL;
    errno = 0;
    unsigned long long seed = strtoull(argv[3], &end, 10);
    if (errno != 0 || end == argv[3] || *end != '\0' || argv[3][0] == '-') {
        fprintf(stderr, "generate: SEED must be a non-negative integer, got '%s'\n", argv[3]);
        return 2;
    }
    { /* the output format is little-endian float32 */
        const float one = 1.0f;
        unsigned char b[sizeof one];
        memcpy(b, &one, sizeof one);
        if (b[3] != 0x3f) {
            fprintf(stderr, "generate: this example writes host floats; expected a little-endian machine\n");
            return 1;
        }
    }

    LgModel *model = NULL;
    LgStatus st = lg_model_load(bundle, backend, &model);
    if (st != LG_STATUS_OK) return fail("loading the bundle", st);

    LgStreamOptions opts = lg_stream_options_default();
    opts.seed = (uint64_t)seed;
    LgStream *stream = NULL;
    st = lg_stream_new(model, &opts, &stream);
    if (st != LG_STATUS_OK) {
        int code = fail("creating a stream", st);
        lg_model_free(model);
        return code;
    }

    /* the whole file, as `livegesture generate` (a push loop: lg_stream_push + lg_stream_finish) */
    size_t ready = 0;
    st = lg_stream_generate_wav(stream, wav, &ready);
    if (st != LG_STATUS_OK) {
        int code = fail("generating", st);
        lg_stream_free(stream);
        lg_model_free(model);
        return code;
    }

    static float poses[BATCH * LG_POSE_DIM];
    size_t total = 0, got = 0;
    int code = 0;
    do {
        st = lg_stream_read(stream, BATCH, poses, NULL, NULL, NULL, &got);
        if (st != LG_STATUS_OK) {
            code = fail("reading frames", st);
            break;
        }
        if (fwrite(poses, sizeof(float) * LG_POSE_DIM, got, stdout) != got) {
            fprintf(stderr, "generate: writing to stdout failed\n");
            code = 1;
            break;
        }
        total += got;
    } while (got > 0);
    if (code == 0 && fflush(stdout) != 0) {
        fprintf(stderr, "generate: writing to stdout failed\n");
        code = 1;
    }
    if (code == 0) fprintf(stderr, "generate: %zu frames x %d poses (float32) from %s\n", total, LG_POSE_DIM, wav);

    lg_stream_free(stream);
    lg_model_free(model);
    return code;
}
