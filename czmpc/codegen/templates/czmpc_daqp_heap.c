/*
 * czmpc_daqp_heap.c: the static arena DAQP's set-up takes its workspace from
 * (czmpc_daqp_heap.h). Bump allocation in 16-byte pieces; nothing is ever returned.
 */
#include "czmpc_daqp_heap.h"

#include <string.h>

#include "czmpc_daqp.h"

#define PIECE 16u
#define N_PIECES ((CZMPC_DAQP_ARENA_BYTES + PIECE - 1u) / PIECE)

typedef union {
    double d;
    long l;
    void *p;
    unsigned char bytes[PIECE];
} piece_t;

static piece_t arena[N_PIECES];
static size_t next_piece = 0;
static int is_open = 0;
static unsigned long n_refused = 0;

void *czmpc_daqp_malloc(size_t size)
{
    /* malloc(0) (a QP without general rows asks for its 0 x n matrix) gets a piece of its
       own: a pointer DAQP may keep and never reads, as the C library's malloc would give */
    size_t pieces = size == 0 ? 1u : (size + PIECE - 1u) / PIECE;
    void *out;
    if (!is_open || pieces > N_PIECES - next_piece) {
        ++n_refused;
        return NULL;
    }
    out = &arena[next_piece];
    next_piece += pieces;
    return out;
}

void *czmpc_daqp_calloc(size_t count, size_t size)
{
    void *out;
    if (size != 0 && count > ((size_t)-1) / size) {
        ++n_refused;
        return NULL;
    }
    out = czmpc_daqp_malloc(count * size);
    if (out != NULL) memset(out, 0, count * size);
    return out;
}

void *czmpc_daqp_realloc(void *ptr, size_t size)
{
    if (ptr == NULL) return czmpc_daqp_malloc(size);
    ++n_refused;   /* DAQP 0.11 never grows a block; a request to is refused */
    return NULL;
}

void czmpc_daqp_free(void *ptr)
{
    (void)ptr;     /* the arena is reused from the start at the next open */
}

void czmpc_daqp_arena_open(void)
{
    next_piece = 0;
    n_refused = 0;
    is_open = 1;
}

void czmpc_daqp_arena_seal(void)
{
    is_open = 0;
}

size_t czmpc_daqp_arena_used(void)
{
    return next_piece * PIECE;
}

unsigned long czmpc_daqp_arena_refused(void)
{
    return n_refused;
}
