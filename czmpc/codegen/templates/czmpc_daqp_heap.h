/*
 * czmpc_daqp_heap.h: DAQP's workspace in a static arena instead of the heap.
 *
 * DAQP's set-up (setup_daqp) takes its arrays from malloc and calloc. The generated
 * step compiles DAQP's sources with this header forced in (-include czmpc_daqp_heap.h
 * -DCZMPC_DAQP_REDIRECT): their malloc, calloc, realloc and free become the functions
 * below, which hand out pieces of one static array sized at generation time
 * (CZMPC_DAQP_ARENA_BYTES, czmpc_daqp.h). czmpc_init opens the arena, runs DAQP's own
 * setup_daqp (the same arithmetic as the Python controller's daqp.Model.setup) and
 * seals it: every later request is refused (NULL) and counted, free does nothing. No
 * object of the step refers to the C library's allocator (tests/codegen).
 */
#ifndef CZMPC_DAQP_HEAP_H
#define CZMPC_DAQP_HEAP_H

#include <stddef.h>
#include <stdlib.h>

void *czmpc_daqp_malloc(size_t size);
void *czmpc_daqp_calloc(size_t count, size_t size);
void *czmpc_daqp_realloc(void *ptr, size_t size);
void czmpc_daqp_free(void *ptr);

/* Start handing out the arena from its beginning (czmpc_init, before setup_daqp). */
void czmpc_daqp_arena_open(void);
/* Refuse every later request (czmpc_init, after setup_daqp). */
void czmpc_daqp_arena_seal(void);
/* Bytes handed out since the last open. */
size_t czmpc_daqp_arena_used(void);
/* Requests refused: after the seal, or beyond the arena. 0 in a working step. */
unsigned long czmpc_daqp_arena_refused(void);

#ifdef CZMPC_DAQP_REDIRECT
#define malloc(size) czmpc_daqp_malloc(size)
#define calloc(count, size) czmpc_daqp_calloc((count), (size))
#define realloc(ptr, size) czmpc_daqp_realloc((ptr), (size))
#define free(ptr) czmpc_daqp_free(ptr)
#endif

#endif /* CZMPC_DAQP_HEAP_H */
