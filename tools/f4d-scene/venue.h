/* venue.h - `f4d-scene venue`: randomised multi-person training takes with
 * exact ground truth (venue.c has the layout of the output directory).
 *
 *     if (argc > 1 && !strcmp(argv[1], "venue"))
 *         return venue_main(argc - 1, argv + 1);   // argv[0] is then "venue"
 *
 * Returns the process exit status: 0, 1 (I/O or library error), 2 (usage). */
#ifndef F4D_VENUE_H
#define F4D_VENUE_H

int venue_main(int argc, char **argv);

#endif /* F4D_VENUE_H */
