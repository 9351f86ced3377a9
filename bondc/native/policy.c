/* bondc's run-loop functions as a library of their own (bondc.runtime.native.load_policy), built
   once per machine for the Python run loop: Filippov sliding (filippov.c) and the location of ends
   and dips (locate.c). The CVODE driver and an FMU's engine include the same two files. */
#include "filippov.c"
#include "locate.c"
