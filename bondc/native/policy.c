/* bondc's run-loop functions as a library of their own (bondc.runtime.native.load_policy), built
   once per machine for the Python run loop: Filippov sliding (filippov.c), the when clauses
   (events.c) and the location of ends and dips (locate.c). The CVODE driver and an FMU's engine
   include the same three files. */
#include "filippov.c"
#include "events.c"
#include "locate.c"
