MODULE CellctlServer
    !***********************************************************************************
    ! cellctl ABB driver, line protocol 1: the socket half.
    !
    ! Load into a second, non-motion NORMAL task (e.g. T_CELLCTL; needs the Multitasking
    ! option), next to CellctlMotion.mod in the motion task. This task serves one TCP
    ! client at a time: ASCII lines of at most 80 characters including the newline,
    ! "<id> <VERB> [args]" in, "<id> <STATUS> [data]" out, every reply carrying the id of
    ! its request. Motions are handed to the motion task; this task stays free meanwhile,
    ! so PING, GETC, GETJ, STATE and STOP are answered while the robot moves. GRIP switches
    ! the gripper's vacuum output here, and only while the robot stands still. STREAM 1/0
    ! has the motion task start or stop EGM's Position Stream; the stream goes on while
    ! later moves run, and STOP, BYE or the client's going away end it.
    !
    ! The verbs, replies and error codes are listed in drivers/abb_robot/README.md, which
    ! is generated from drivers/abb_robot/protocol.py; keep the numbers in step (a test
    ! checks the constants below against it).
    !***********************************************************************************

    ! ---- settings ----
    CONST num CELLCTL_PROTOCOL:=1;
    CONST num CELLCTL_PORT:=30100;
    ! Address to listen on; "" = the controller's LAN address (127.0.0.1 on a virtual controller).
    CONST string CELLCTL_BIND_ADDRESS:="";
    CONST string CELLCTL_MOTION_TASK:="T_ROB1";
    ! Digital output cross-connected to the system output "Motor On" (optional; without it
    ! STATE reports motors -1 = unknown).
    CONST string CELLCTL_MOTORS_SIGNAL:="doCellctlMotorsOn";
    ! Socket poll while waiting for a line (s); a finished motion is reported within this.
    CONST num CELLCTL_POLL:=0.05;
    ! A client that sends nothing for this long (s) is dropped (cellctl pings every second).
    CONST num CELLCTL_IDLE_TIMEOUT:=10;
    ! The gripper (GRIP 1 = vacuum on, hold; GRIP 0 = off, release): the digital output that
    ! switches the vacuum, and the time (s) the vacuum needs to build up or fall off after
    ! switching, waited before GRIP answers. TASK PERS (this task's own, not shared): edit
    ! them here, or in the program data window while commissioning the vacuum.
    TASK PERS string grip_signal:="doCellctlVacuum";
    TASK PERS num grip_settle:=0.5;

    ! ---- error codes (abb_robot.protocol.ErrorCode) ----
    CONST num CELLCTL_E_SYNTAX:=100;
    CONST num CELLCTL_E_TOO_LONG:=101;
    CONST num CELLCTL_E_VERSION:=102;
    CONST num CELLCTL_E_NO_HELLO:=103;
    CONST num CELLCTL_E_BUSY:=110;
    CONST num CELLCTL_E_NO_TARGET:=111;
    CONST num CELLCTL_E_SEQUENCE:=112;
    CONST num CELLCTL_E_UNKNOWN_TOOL:=120;
    CONST num CELLCTL_E_UNKNOWN_WOBJ:=121;
    CONST num CELLCTL_E_RANGE:=122;
    CONST num CELLCTL_E_REACH:=130;
    CONST num CELLCTL_E_JOINT_LIMIT:=131;
    CONST num CELLCTL_E_STOPPED:=140;
    CONST num CELLCTL_E_MOTION:=141;
    CONST num CELLCTL_E_EGM_COMM:=150;
    CONST num CELLCTL_E_EGM_SETUP:=151;
    CONST num CELLCTL_E_EGM_STATE:=152;
    CONST num CELLCTL_E_GRIPPER:=160;
    CONST num CELLCTL_E_INTERNAL:=199;

    ! ---- command kinds (same numbers in CellctlMotion.mod) ----
    CONST num CMD_MOVEL:=1;
    CONST num CMD_MOVEJ:=2;
    CONST num CMD_TOOL:=3;
    CONST num CMD_WOBJ:=4;
    CONST num CMD_EGM:=5;
    CONST num CMD_STREAM:=6;

    ! ---- task-global persistents; their initial values are in CellctlMotion.mod ----
    PERS num cellctl_cmd_seq;
    PERS num cellctl_done_seq;
    PERS num cellctl_cmd_kind;
    PERS robtarget cellctl_cmd_target;
    PERS string cellctl_cmd_name;
    PERS num cellctl_cmd_args{3};
    PERS num cellctl_result_code;
    PERS string cellctl_result_text;
    PERS num cellctl_stop_seq;
    PERS speeddata cellctl_speed;
    PERS zonedata cellctl_zone;
    PERS tooldata cellctl_tool;
    PERS wobjdata cellctl_wobj;
    PERS bool cellctl_stream_on;

    VAR socketdev server_sock;
    VAR socketdev client_sock;
    VAR string rx_rest:="";
    VAR string rx_line:="";
    VAR bool rx_discard:=FALSE;
    VAR bool hello_done:=FALSE;
    VAR bool pos_staged:=FALSE;
    VAR bool ori_staged:=FALSE;
    VAR pos staged_pos;
    VAR orient staged_ori;
    VAR num active_id:=0;
    VAR num active_kind:=0;
    VAR clock idle_clock;
    VAR signaldo motors_sig;
    VAR bool motors_known:=FALSE;
    VAR signaldo grip_sig;
    ! the request being handled: its fields and numeric arguments
    VAR string tok{8};
    VAR num ntok:=0;
    VAR num arg{4};

    PROC main()
        BindMotorsSignal;
        WHILE TRUE DO
            ServeForever;
            WaitTime 1;
        ENDWHILE
    ENDPROC

    PROC ServeForever()
        SocketClose client_sock;
        SocketClose server_sock;
        SocketCreate server_sock;
        SocketBind server_sock,BindAddress(),CELLCTL_PORT;
        SocketListen server_sock;
        WHILE TRUE DO
            SocketAccept server_sock,client_sock\Time:=WAIT_MAX;
            ServeClient;
            SocketClose client_sock;
        ENDWHILE
    ERROR
        TPWrite "cellctl server: socket error "\Num:=ERRNO;
        SocketClose client_sock;
        SocketClose server_sock;
        RETURN;
    ENDPROC

    FUNC string BindAddress()
        IF CELLCTL_BIND_ADDRESS<>"" RETURN CELLCTL_BIND_ADDRESS;
        IF RobOS() RETURN GetSysInfo(\LanIp);
        RETURN "127.0.0.1";
    ENDFUNC

    PROC BindMotorsSignal()
        motors_known:=FALSE;
        AliasIO CELLCTL_MOTORS_SIGNAL,motors_sig;
        motors_known:=TRUE;
    ERROR
        ! The signal is not configured: STATE reports motors as unknown (-1).
        motors_known:=FALSE;
        RETURN;
    ENDPROC

    ! ---------------------------------------------------------------- one client
    PROC ServeClient()
        VAR string line;

        rx_rest:="";
        rx_line:="";
        rx_discard:=FALSE;
        hello_done:=FALSE;
        pos_staged:=FALSE;
        ori_staged:=FALSE;
        active_id:=0;
        ClkReset idle_clock;
        ClkStart idle_clock;
        WHILE TRUE DO
            ReportFinished;
            IF ReadLine(line) THEN
                ClkReset idle_clock;
                ClkStart idle_clock;
                IF HandleLine(line) THEN
                    ! BYE: no motion goes on without its client
                    StopIfBusy;
                    RETURN;
                ENDIF
            ELSEIF ClkRead(idle_clock)>CELLCTL_IDLE_TIMEOUT THEN
                StopIfBusy;
                RETURN;
            ENDIF
        ENDWHILE
    ERROR
        IF ERRNO=ERR_SOCK_CLOSED THEN
            ! The client went away: stop its motion, listen again.
            StopIfBusy;
            RETURN;
        ENDIF
        RAISE;
    ENDPROC

    FUNC bool Busy()
        RETURN cellctl_cmd_seq<>cellctl_done_seq;
    ENDFUNC

    PROC StopIfBusy()
        ! No motion and no position stream goes on without its client.
        IF Busy() OR cellctl_stream_on THEN
            cellctl_stop_seq:=cellctl_stop_seq+1;
            WaitUntil NOT Busy() AND NOT cellctl_stream_on\MaxTime:=5;
        ENDIF
        active_id:=0;
    ERROR
        IF ERRNO=ERR_WAIT_MAXTIME THEN
            active_id:=0;
            RETURN;
        ENDIF
    ENDPROC

    PROC ReportFinished()
        ! Answer the command handed to the motion task once it is done.
        IF active_id>0 AND NOT Busy() THEN
            IF cellctl_result_code<>0 THEN
                ReplyErr active_id,cellctl_result_code,cellctl_result_text;
            ELSEIF active_kind=CMD_TOOL OR active_kind=CMD_WOBJ THEN
                Reply active_id,"OK "+cellctl_cmd_name;
            ELSEIF active_kind=CMD_STREAM THEN
                Reply active_id,"OK "+NumToStr(cellctl_cmd_args{1},0);
            ELSE
                Reply active_id,"DONE";
            ENDIF
            active_id:=0;
        ENDIF
    ENDPROC

    FUNC bool ReadLine(INOUT string line)
        ! One complete line (without its newline); FALSE when none came within CELLCTL_POLL.
        ! rx_rest holds received characters not yet looked at, rx_line a line begun.
        VAR string chunk;
        VAR string head;
        VAR num nl;

        WHILE TRUE DO
            IF rx_rest="" THEN
                SocketReceive client_sock\Str:=chunk\Time:=CELLCTL_POLL;
                rx_rest:=chunk;
            ENDIF
            nl:=StrFind(rx_rest,1,"\0A");
            IF nl>StrLen(rx_rest) THEN
                ! no newline yet: keep the beginning of the line
                IF rx_discard THEN
                    rx_rest:="";
                ELSEIF StrLen(rx_line)+StrLen(rx_rest)>79 THEN
                    ReplyErr 0,CELLCTL_E_TOO_LONG,"line over 80 chars";
                    rx_line:="";
                    rx_rest:="";
                    rx_discard:=TRUE;
                ELSE
                    rx_line:=rx_line+rx_rest;
                    rx_rest:="";
                ENDIF
            ELSE
                head:="";
                IF nl>1 head:=StrPart(rx_rest,1,nl-1);
                IF nl<StrLen(rx_rest) THEN
                    rx_rest:=StrPart(rx_rest,nl+1,StrLen(rx_rest)-nl);
                ELSE
                    rx_rest:="";
                ENDIF
                IF rx_discard THEN
                    ! the end of an overlong line: dropped
                    rx_discard:=FALSE;
                ELSEIF StrLen(rx_line)+StrLen(head)>79 THEN
                    ReplyErr 0,CELLCTL_E_TOO_LONG,"line over 80 chars";
                    rx_line:="";
                ELSE
                    line:=rx_line+head;
                    rx_line:="";
                    IF StrLen(line)>0 THEN
                        IF StrPart(line,StrLen(line),1)="\0D" line:=StrPart(line,1,StrLen(line)-1);
                    ENDIF
                    RETURN TRUE;
                ENDIF
            ENDIF
        ENDWHILE
    ERROR
        IF ERRNO=ERR_SOCK_TIMEOUT THEN
            RETURN FALSE;
        ENDIF
        RAISE;
    ENDFUNC

    ! ---------------------------------------------------------------- replies
    PROC SendLine(string line)
        ! line is at most 79 characters; the newline makes 80.
        SocketSend client_sock\Str:=line+"\0A";
    ENDPROC

    PROC Reply(num id,string rest)
        SendLine NumToStr(id,0)+" "+rest;
    ENDPROC

    PROC ReplyErr(num id,num code,string text)
        VAR string head;
        VAR num room;

        head:=NumToStr(id,0)+" ERR "+NumToStr(code,0)+" ";
        room:=79-StrLen(head);
        IF StrLen(text)>room THEN
            SendLine head+StrPart(text,1,room);
        ELSE
            SendLine head+text;
        ENDIF
    ENDPROC

    ! ---------------------------------------------------------------- parsing
    PROC Tokenize(string line)
        ! Fields separated by one or more spaces.
        VAR num pos:=1;
        VAR num stop;

        ntok:=0;
        WHILE pos<=StrLen(line) DO
            pos:=StrFind(line,pos," "\NotInSet);
            IF pos>StrLen(line) RETURN;
            stop:=StrFind(line,pos," ");
            IF ntok>=8 THEN
                ! more fields than any verb takes: the arity check refuses the line
                ntok:=9;
                RETURN;
            ENDIF
            ntok:=ntok+1;
            tok{ntok}:=StrPart(line,pos,stop-pos);
            pos:=stop;
        ENDWHILE
    ENDPROC

    FUNC bool IsNumber(string t,INOUT num value)
        ! A plain decimal number (digits, one point, a sign): what protocol.py accepts.
        IF StrLen(t)=0 RETURN FALSE;
        IF StrFind(t,1,STR_DIGIT+".+-"\NotInSet)<=StrLen(t) RETURN FALSE;
        IF StrFind(t,1,STR_DIGIT)>StrLen(t) RETURN FALSE;
        RETURN StrToVal(t,value);
    ENDFUNC

    FUNC num Least(num a,num b)
        IF a<b RETURN a;
        RETURN b;
    ENDFUNC

    FUNC bool IsName(string t)
        ! A RAPID identifier: a letter, then letters, digits or '_', 32 at most.
        IF StrLen(t)<1 OR StrLen(t)>32 RETURN FALSE;
        IF StrFind(StrPart(t,1,1),1,STR_UPPER+STR_LOWER)>1 RETURN FALSE;
        RETURN StrFind(t,1,STR_UPPER+STR_LOWER+STR_DIGIT+"_"\NotInSet)>StrLen(t);
    ENDFUNC

    FUNC num Arity(string verb)
        ! Number of arguments of a verb; -1 if the verb is unknown.
        TEST verb
        CASE "HELLO","TOOL","WOBJ","ZONE","GRIP","STREAM":
            RETURN 1;
        CASE "PING","BYE","MOVEL","MOVEJ","STOP","GETC","GETJ","STATE":
            RETURN 0;
        CASE "SPEED":
            RETURN 2;
        CASE "POS","EGM":
            RETURN 3;
        CASE "ORI":
            RETURN 4;
        DEFAULT:
            RETURN -1;
        ENDTEST
    ENDFUNC

    FUNC bool WhileMoving(string verb)
        ! Verbs answered while a motion or EGM session runs; the others get BUSY.
        TEST verb
        CASE "HELLO","PING","BYE","POS","ORI","STOP","GETC","GETJ","STATE":
            RETURN TRUE;
        DEFAULT:
            RETURN FALSE;
        ENDTEST
    ENDFUNC

    ! ---------------------------------------------------------------- requests
    FUNC bool HandleLine(string line)
        ! Answer one request; TRUE when the client said BYE.
        VAR num id;
        VAR string verb;
        VAR num n;

        Tokenize line;
        IF ntok=0 THEN
            ReplyErr 0,CELLCTL_E_SYNTAX,"empty line";
            RETURN FALSE;
        ENDIF
        IF StrLen(tok{1})>5 OR StrFind(tok{1},1,STR_DIGIT\NotInSet)<=StrLen(tok{1}) THEN
            ReplyErr 0,CELLCTL_E_SYNTAX,"line does not start with a request id";
            RETURN FALSE;
        ENDIF
        IF NOT StrToVal(tok{1},id) OR id<1 THEN
            ReplyErr 0,CELLCTL_E_SYNTAX,"line does not start with a request id";
            RETURN FALSE;
        ENDIF
        IF ntok<2 THEN
            ReplyErr id,CELLCTL_E_SYNTAX,"request id without a verb";
            RETURN FALSE;
        ENDIF
        verb:=StrMap(tok{2},STR_LOWER,STR_UPPER);
        n:=Arity(verb);
        IF n<0 THEN
            ReplyErr id,CELLCTL_E_SYNTAX,"unknown verb "+StrPart(tok{2},1,Least(StrLen(tok{2}),12));
            RETURN FALSE;
        ENDIF
        IF ntok-2<>n THEN
            ReplyErr id,CELLCTL_E_SYNTAX,verb+" takes "+NumToStr(n,0)+" args, got "+NumToStr(ntok-2,0);
            RETURN FALSE;
        ENDIF
        IF verb="TOOL" OR verb="WOBJ" THEN
            IF NOT IsName(tok{3}) THEN
                ReplyErr id,CELLCTL_E_RANGE,StrPart(tok{3},1,Least(StrLen(tok{3}),32))+" is not a RAPID name";
                RETURN FALSE;
            ENDIF
        ELSE
            FOR i FROM 1 TO n DO
                IF NOT IsNumber(tok{i+2},arg{i}) THEN
                    ReplyErr id,CELLCTL_E_SYNTAX,"argument "+NumToStr(i,0)+" is not a decimal number";
                    RETURN FALSE;
                ENDIF
            ENDFOR
            IF verb="HELLO" AND StrFind(tok{3},1,STR_DIGIT+"+-"\NotInSet)<=StrLen(tok{3}) THEN
                ReplyErr id,CELLCTL_E_SYNTAX,"version is not an integer";
                RETURN FALSE;
            ENDIF
            IF verb="GRIP" AND StrFind(tok{3},1,STR_DIGIT+"+-"\NotInSet)<=StrLen(tok{3}) THEN
                ReplyErr id,CELLCTL_E_SYNTAX,"hold is not an integer";
                RETURN FALSE;
            ENDIF
            IF verb="STREAM" AND StrFind(tok{3},1,STR_DIGIT+"+-"\NotInSet)<=StrLen(tok{3}) THEN
                ReplyErr id,CELLCTL_E_SYNTAX,"on is not an integer";
                RETURN FALSE;
            ENDIF
        ENDIF
        IF NOT hello_done AND verb<>"HELLO" AND verb<>"BYE" THEN
            ReplyErr id,CELLCTL_E_NO_HELLO,"send HELLO first";
            RETURN FALSE;
        ENDIF
        IF Busy() AND NOT WhileMoving(verb) THEN
            ReplyErr id,CELLCTL_E_BUSY,verb+" refused: a motion is running";
            RETURN FALSE;
        ENDIF
        IF cellctl_stream_on AND (verb="TOOL" OR verb="WOBJ") THEN
            ! The stream's feedback frame was fixed by EGMActPose at STREAM 1.
            ReplyErr id,CELLCTL_E_BUSY,verb+" refused: a position stream runs (STREAM 0 first)";
            RETURN FALSE;
        ENDIF
        TEST verb
        CASE "HELLO":
            DoHello id;
        CASE "PING":
            Reply id,"PONG";
        CASE "BYE":
            Reply id,"OK";
            RETURN TRUE;
        CASE "TOOL":
            cellctl_cmd_name:=tok{3};
            Forward id,CMD_TOOL;
        CASE "WOBJ":
            cellctl_cmd_name:=tok{3};
            Forward id,CMD_WOBJ;
        CASE "SPEED":
            DoSpeed id;
        CASE "ZONE":
            DoZone id;
        CASE "POS":
            DoPos id;
        CASE "ORI":
            DoOri id;
        CASE "MOVEL":
            DoMove id,CMD_MOVEL;
        CASE "MOVEJ":
            DoMove id,CMD_MOVEJ;
        CASE "EGM":
            DoEgm id;
        CASE "STOP":
            DoStop id;
        CASE "GETC":
            DoGetc id;
        CASE "GETJ":
            DoGetj id;
        CASE "STATE":
            DoState id;
        CASE "GRIP":
            DoGrip id;
        CASE "STREAM":
            DoStream id;
        ENDTEST
        RETURN FALSE;
    ENDFUNC

    PROC Forward(num id,num kind)
        ! Hand a command to the motion task; ReportFinished answers it.
        cellctl_cmd_kind:=kind;
        active_id:=id;
        active_kind:=kind;
        cellctl_cmd_seq:=cellctl_cmd_seq+1;
    ENDPROC

    PROC DoHello(num id)
        IF arg{1}<>CELLCTL_PROTOCOL THEN
            ReplyErr id,CELLCTL_E_VERSION,"version "+NumToStr(arg{1},0)+" not supported, server speaks "+NumToStr(CELLCTL_PROTOCOL,0);
            RETURN;
        ENDIF
        hello_done:=TRUE;
        pos_staged:=FALSE;
        ori_staged:=FALSE;
        Reply id,"OK "+NumToStr(CELLCTL_PROTOCOL,0)+" "+Field(GetSysInfo(\RobotType))+" "+Field(GetSysInfo(\SWVersion));
    ENDPROC

    FUNC string Field(string s)
        ! A text as one field: spaces become '_', at most 28 characters, never empty.
        VAR string t;

        t:=StrMap(s," ","_");
        IF StrLen(t)>28 t:=StrPart(t,1,28);
        IF t="" t:="-";
        RETURN t;
    ENDFUNC

    PROC DoSpeed(num id)
        IF arg{1}<=0 OR arg{1}>7000 OR arg{2}<=0 OR arg{2}>1000 THEN
            ReplyErr id,CELLCTL_E_RANGE,"speed needs 0<v_tcp<=7000 mm/s, 0<v_ori<=1000 deg/s";
            RETURN;
        ENDIF
        cellctl_speed:=[arg{1},arg{2},5000,1000];
        Reply id,"OK "+NumToStr(arg{1},1)+" "+NumToStr(arg{2},1);
    ENDPROC

    PROC DoZone(num id)
        VAR num z;

        z:=arg{1};
        IF z<0 OR z>2000 THEN
            ReplyErr id,CELLCTL_E_RANGE,"zone needs 0<=zone_mm<=2000 (0 = fine)";
            RETURN;
        ENDIF
        IF z=0 THEN
            cellctl_zone:=[TRUE,0,0,0,0,0,0];
        ELSE
            cellctl_zone:=[FALSE,z,1.5*z,1.5*z,0.15*z,1.5*z,0.15*z];
        ENDIF
        Reply id,"OK "+NumToStr(z,1);
    ENDPROC

    PROC DoPos(num id)
        IF Abs(arg{1})>99999 OR Abs(arg{2})>99999 OR Abs(arg{3})>99999 THEN
            ReplyErr id,CELLCTL_E_RANGE,"position beyond +-99999 mm";
            RETURN;
        ENDIF
        staged_pos:=[arg{1},arg{2},arg{3}];
        pos_staged:=TRUE;
        ori_staged:=FALSE;
        Reply id,"OK";
    ENDPROC

    PROC DoOri(num id)
        VAR num norm;

        IF NOT pos_staged THEN
            ReplyErr id,CELLCTL_E_SEQUENCE,"ORI needs a POS before it";
            RETURN;
        ENDIF
        norm:=Sqrt(arg{1}*arg{1}+arg{2}*arg{2}+arg{3}*arg{3}+arg{4}*arg{4});
        IF Abs(norm-1)>0.001 THEN
            ReplyErr id,CELLCTL_E_RANGE,"quaternion norm "+NumToStr(norm,6)+" is not 1";
            RETURN;
        ENDIF
        staged_ori:=NOrient([arg{1},arg{2},arg{3},arg{4}]);
        ori_staged:=TRUE;
        Reply id,"OK";
    ENDPROC

    PROC DoMove(num id,num kind)
        IF NOT (pos_staged AND ori_staged) THEN
            ReplyErr id,CELLCTL_E_NO_TARGET,"stage POS and ORI before a move";
            RETURN;
        ENDIF
        cellctl_cmd_target.trans:=staged_pos;
        cellctl_cmd_target.rot:=staged_ori;
        pos_staged:=FALSE;
        ori_staged:=FALSE;
        Reply id,"ACK";
        Forward id,kind;
    ENDPROC

    PROC DoEgm(num id)
        IF cellctl_stream_on THEN
            ! One EGM user at a time on the UdpUc device: the stream or a guidance session.
            ReplyErr id,CELLCTL_E_BUSY,"EGM refused: a position stream runs";
            RETURN;
        ENDIF
        IF arg{1}<=0 OR arg{2}<=0 OR arg{3}<=0 OR arg{3}>3600 THEN
            ReplyErr id,CELLCTL_E_RANGE,"EGM needs band_mm>0, band_deg>0, 0<cond_s<=3600";
            RETURN;
        ENDIF
        cellctl_cmd_args:=[arg{1},arg{2},arg{3}];
        Reply id,"ACK";
        Forward id,CMD_EGM;
    ENDPROC

    PROC DoStop(num id)
        VAR string was_moving:="0";

        IF Busy() was_moving:="1";
        IF Busy() OR cellctl_stream_on THEN
            ! The motion task's trap ends the position stream and stops the robot;
            ! ReportFinished then answers the stopped motion with ERR 140.
            cellctl_stop_seq:=cellctl_stop_seq+1;
        ENDIF
        Reply id,"OK "+was_moving;
    ENDPROC

    PROC DoStream(num id)
        ! STREAM 1 starts (or restarts) EGM's Position Stream, STREAM 0 stops it; the motion
        ! task runs it (RunStream) and ReportFinished answers "OK 1" or "OK 0". HandleLine has
        ! refused it while a motion runs (BUSY): the cell starts the stream before its moves
        ! and stops it after them.
        IF arg{1}<>0 AND arg{1}<>1 THEN
            ReplyErr id,CELLCTL_E_RANGE,"STREAM needs 1 (start) or 0 (stop)";
            RETURN;
        ENDIF
        cellctl_cmd_args:=[arg{1},0,0];
        Forward id,CMD_STREAM;
    ENDPROC

    PROC DoGetc(num id)
        VAR robtarget p;

        p:=CRobT(\TaskName:=CELLCTL_MOTION_TASK\Tool:=cellctl_tool\WObj:=cellctl_wobj);
        Reply id,"DATA POS "+NumToStr(p.trans.x,3)+" "+NumToStr(p.trans.y,3)+" "+NumToStr(p.trans.z,3);
        Reply id,"OK ORI "+NumToStr(p.rot.q1,6)+" "+NumToStr(p.rot.q2,6)+" "+NumToStr(p.rot.q3,6)+" "+NumToStr(p.rot.q4,6);
    ENDPROC

    PROC DoGetj(num id)
        VAR jointtarget j;

        j:=CJointT(\TaskName:=CELLCTL_MOTION_TASK);
        Reply id,"OK "+NumToStr(j.robax.rax_1,4)+" "+NumToStr(j.robax.rax_2,4)+" "+NumToStr(j.robax.rax_3,4)+" "
            +NumToStr(j.robax.rax_4,4)+" "+NumToStr(j.robax.rax_5,4)+" "+NumToStr(j.robax.rax_6,4);
    ENDPROC

    PROC DoState(num id)
        VAR string motors:="-1";
        VAR string moving:="0";

        IF motors_known THEN
            motors:=NumToStr(DOutput(motors_sig),0);
        ENDIF
        IF Busy() moving:="1";
        Reply id,"OK "+motors+" "+moving;
    ENDPROC

    PROC DoGrip(num id)
        ! Switch the gripper's vacuum, wait for it to settle, answer. HandleLine has refused
        ! GRIP while a motion runs (BUSY): the glass is never released mid-motion. No motion
        ! can start meanwhile either: this task reads no request until it has answered.
        VAR num step:=0;

        IF arg{1}<>0 AND arg{1}<>1 THEN
            ReplyErr id,CELLCTL_E_RANGE,"GRIP needs 0 (release) or 1 (hold)";
            RETURN;
        ENDIF
        ! Aliased on every GRIP, so a signal name changed in grip_signal takes effect.
        AliasIO grip_signal,grip_sig;
        step:=1;
        SetDO grip_sig,arg{1};
        step:=2;
        IF grip_settle>0 WaitTime grip_settle;
        Reply id,"OK "+NumToStr(arg{1},0);
    ERROR
        IF ERRNO=ERR_SOCK_CLOSED OR ERRNO=ERR_SOCK_TIMEOUT THEN
            ! the client went away while the vacuum settled: ServeClient handles it
            RAISE;
        ENDIF
        IF step=0 THEN
            ReplyErr id,CELLCTL_E_GRIPPER,"no gripper output "+grip_signal;
        ELSE
            ReplyErr id,CELLCTL_E_GRIPPER,"gripper output error "+NumToStr(ERRNO,0);
        ENDIF
        RETURN;
    ENDPROC
ENDMODULE
